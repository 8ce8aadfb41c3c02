//! The occupancy grid on the motion plane (SPEC §6), built incrementally from two sources in
//! whatever frame the given poses live in (the robot's estimated frame in the loop):
//!
//! - **map points**: Gaussian means with their opacity; a cell is occupied when more than
//!   `point_threshold` (release: 25) of them lie in the height band `[band_min, band_max]`
//!   above the floor (0.1–1.3 m); points just above the floor mark observed floor (free).
//!   The counts are recomputed on each call, since the map's Gaussians move and get pruned.
//! - **depth rays**: from the camera centre to each back-projected depth pixel. The part of a
//!   ray inside the height band frees the cells it passes (DDA traversal); an end point in the
//!   band is a hit, an end point on the floor frees its cell. Each frame updates each cell once
//!   (a hit wins over a pass), accumulated as clamped log-odds across frames.
//!
//! [`OccupancyMapper::grid`] combines both and applies the 3×3 morphological opening.

use activemap_geometry::{Intrinsics, Isometry3};
use nalgebra::{Point2, Point3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{PlanningError, require};
use crate::grid::{Cell, CellState, Grid, GridGeometry, OccupancyGrid};
use crate::morphology::open3;
use crate::segment::for_each_ray_cell;

/// Which class the 3×3 opening of SPEC §6 cleans.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum OpeningTarget {
    /// Open the free space (default): free specks and free strips narrower than 3 cells (too
    /// narrow for the 3-cell robot anyway) become unknown; thin walls survive.
    Free,
    /// Open the occupied cells: isolated occupied specks (noise Gaussians) disappear, but so do
    /// walls seen as 1–2-cell lines.
    Occupied,
    /// No morphology.
    None,
}

/// Settings of the occupancy mapper (defaults: SPEC §6 and the release).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OccupancyConfig {
    /// Cell side, metres (SPEC: 0.05).
    pub resolution: f64,
    /// World z of the floor, metres.
    pub floor_z: f64,
    /// Lower end of the obstacle height band above the floor, metres (SPEC: 0.1).
    pub band_min: f64,
    /// Upper end of the obstacle height band above the floor, metres (SPEC: 1.3).
    pub band_max: f64,
    /// A cell is occupied when it holds MORE than this many map points in the band (release: 25).
    pub point_threshold: u32,
    /// Map points with a lower opacity (after the sigmoid) are ignored.
    pub min_opacity: f32,
    /// Points and depth end points within this distance below `floor_z + band_min` (and above
    /// `floor_z − floor_tolerance`) count as observed floor and mark their cell free.
    pub floor_tolerance: f64,
    /// Whether map points on the floor mark their cell free.
    pub floor_points_free: bool,
    /// Depth readings beyond this z-depth (metres) are truncated: they free space up to it but
    /// are not hits.
    pub max_depth: f64,
    /// Use every `pixel_stride`-th pixel in both directions.
    pub pixel_stride: usize,
    /// Log-odds added to a cell hit in a frame.
    pub hit_log_odds: f32,
    /// Log-odds removed from a cell passed (and not hit) in a frame.
    pub miss_log_odds: f32,
    /// Log-odds are clamped to `[-clamp, clamp]` so the map can change its mind.
    pub clamp_log_odds: f32,
    /// The 3×3 opening.
    pub opening: OpeningTarget,
    /// Extra room (metres) added on every side when the grid grows.
    pub grow_margin: f64,
    /// Points and rays beyond `|x|` or `|y|` of this many metres are ignored (bounds memory).
    pub world_limit: f64,
}

impl Default for OccupancyConfig {
    fn default() -> Self {
        Self {
            resolution: 0.05,
            floor_z: 0.0,
            band_min: 0.1,
            band_max: 1.3,
            point_threshold: 25,
            min_opacity: 0.1,
            floor_tolerance: 0.15,
            floor_points_free: true,
            max_depth: 5.0,
            pixel_stride: 1,
            hit_log_odds: 0.85,
            miss_log_odds: 0.4,
            clamp_log_odds: 3.5,
            opening: OpeningTarget::Free,
            grow_margin: 1.0,
            world_limit: 50.0,
        }
    }
}

impl OccupancyConfig {
    /// Checks the ranges of every field.
    pub fn validate(&self) -> Result<(), PlanningError> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        require(
            pos(self.resolution),
            "OccupancyConfig::resolution",
            "must be positive",
        )?;
        require(
            self.floor_z.is_finite(),
            "OccupancyConfig::floor_z",
            "must be finite",
        )?;
        require(
            self.band_min.is_finite() && self.band_max.is_finite() && self.band_min < self.band_max,
            "OccupancyConfig::band_min",
            "band_min must be below band_max, both finite",
        )?;
        require(
            self.floor_tolerance.is_finite() && self.floor_tolerance >= 0.0,
            "OccupancyConfig::floor_tolerance",
            "must be finite and non-negative",
        )?;
        require(
            pos(self.max_depth),
            "OccupancyConfig::max_depth",
            "must be positive",
        )?;
        require(
            self.pixel_stride >= 1,
            "OccupancyConfig::pixel_stride",
            "must be at least 1",
        )?;
        require(
            self.hit_log_odds > 0.0 && self.miss_log_odds > 0.0 && self.clamp_log_odds > 0.0,
            "OccupancyConfig::hit_log_odds",
            "hit, miss and clamp log-odds must be positive",
        )?;
        require(
            self.grow_margin.is_finite() && self.grow_margin >= 0.0,
            "OccupancyConfig::grow_margin",
            "must be finite and non-negative",
        )?;
        require(
            pos(self.world_limit),
            "OccupancyConfig::world_limit",
            "must be positive",
        )?;
        require(
            (0.0..=1.0).contains(&self.min_opacity),
            "OccupancyConfig::min_opacity",
            "must be in [0, 1]",
        )
    }
}

/// What one depth frame did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct DepthUpdateStats {
    /// Pixels with a valid reading that were cast.
    pub rays: usize,
    /// Rays whose end point was an obstacle in the band.
    pub hits: usize,
    /// Cells whose log-odds changed.
    pub cells_updated: usize,
}

/// Per-frame mark of a cell: passed by a ray (free) or hit (occupied; wins).
const MARK_NONE: u8 = 0;
const MARK_FREE: u8 = 1;
const MARK_HIT: u8 = 2;

/// One depth ray reduced to the motion plane: the band part `from → to` to free, and its end.
struct PlaneRay {
    band: Option<(Point2<f64>, Point2<f64>)>,
    end: Point2<f64>,
    end_mark: u8,
}

/// The incremental occupancy mapper.
#[derive(Debug, Clone)]
pub struct OccupancyMapper {
    config: OccupancyConfig,
    log_odds: Grid<f32>,
    seen: Grid<bool>,
    band_points: Grid<u32>,
    floor_points: Grid<u32>,
    frame_mark: Vec<u8>,
}

impl OccupancyMapper {
    /// An empty map (all unknown) initially covering `[min, max]`; it grows as needed.
    pub fn new(
        config: OccupancyConfig,
        min: Point2<f64>,
        max: Point2<f64>,
    ) -> Result<Self, PlanningError> {
        config.validate()?;
        let g = GridGeometry::from_bounds(min, max, config.resolution, 0.0)?;
        Ok(Self {
            config,
            log_odds: Grid::filled(g, 0.0),
            seen: Grid::filled(g, false),
            band_points: Grid::filled(g, 0),
            floor_points: Grid::filled(g, 0),
            frame_mark: vec![MARK_NONE; g.len()],
        })
    }

    /// The settings.
    pub fn config(&self) -> &OccupancyConfig {
        &self.config
    }

    /// Current placement of the grid.
    pub fn geometry(&self) -> &GridGeometry {
        &self.log_odds.geometry
    }

    fn within_limit(&self, p: Point2<f64>) -> bool {
        p.x.abs() <= self.config.world_limit && p.y.abs() <= self.config.world_limit
    }

    /// Grows every layer so that the box `[min, max]` fits.
    fn ensure_contains(&mut self, min: Point2<f64>, max: Point2<f64>) -> Result<(), PlanningError> {
        let (g, shift) = self
            .geometry()
            .grown_to_include(min, max, self.config.grow_margin)?;
        if g != *self.geometry() {
            self.log_odds = self.log_odds.reshaped(g, shift, 0.0);
            self.seen = self.seen.reshaped(g, shift, false);
            self.band_points = self.band_points.reshaped(g, shift, 0);
            self.floor_points = self.floor_points.reshaped(g, shift, 0);
            self.frame_mark = vec![MARK_NONE; g.len()];
        }
        Ok(())
    }

    fn band_z(&self) -> (f64, f64) {
        (
            self.config.floor_z + self.config.band_min,
            self.config.floor_z + self.config.band_max,
        )
    }

    fn is_floor_z(&self, z: f64) -> bool {
        let (lo, _) = self.band_z();
        z < lo && z >= self.config.floor_z - self.config.floor_tolerance
    }

    /// Replaces the map-point layer with the given Gaussian means and opacities (post-sigmoid,
    /// in [0, 1]), e.g. the whole current 3DGS map. Points with a NaN or infinite mean or
    /// opacity are ignored; returns how many (for the caller to report). Fails when the slices
    /// differ in length.
    pub fn set_map_points(
        &mut self,
        means: &[[f32; 3]],
        opacities: &[f32],
    ) -> Result<usize, PlanningError> {
        if means.len() != opacities.len() {
            return Err(PlanningError::SizeMismatch {
                what: "map point opacities",
                expected: means.len(),
                got: opacities.len(),
            });
        }
        let (lo, hi) = self.band_z();
        let cfg = self.config;
        let floor_lo = cfg.floor_z - cfg.floor_tolerance;
        let keep = move |m: &[f32; 3], o: f32| {
            let z = m[2] as f64;
            o.is_finite()
                && o >= cfg.min_opacity
                && m.iter().all(|v| v.is_finite())
                && (m[0] as f64).abs() <= cfg.world_limit
                && (m[1] as f64).abs() <= cfg.world_limit
                && ((z >= lo && z <= hi) || (cfg.floor_points_free && z < lo && z >= floor_lo))
        };
        let mut bounds: Option<(Point2<f64>, Point2<f64>)> = None;
        for (m, o) in means.iter().zip(opacities) {
            if keep(m, *o) {
                let p = Point2::new(m[0] as f64, m[1] as f64);
                bounds = Some(match bounds {
                    None => (p, p),
                    Some((a, b)) => (a.inf(&p), b.sup(&p)),
                });
            }
        }
        if let Some((a, b)) = bounds {
            self.ensure_contains(a, b)?;
        }
        self.band_points.data.iter_mut().for_each(|c| *c = 0);
        self.floor_points.data.iter_mut().for_each(|c| *c = 0);
        let g = *self.geometry();
        for (m, o) in means.iter().zip(opacities) {
            if !keep(m, *o) {
                continue;
            }
            let Some(i) = g.index(g.cell_of(Point2::new(m[0] as f64, m[1] as f64))) else {
                continue;
            };
            let z = m[2] as f64;
            if z >= lo && z <= hi {
                self.band_points.data[i] += 1;
            } else {
                self.floor_points.data[i] += 1;
            }
        }
        let non_finite = means
            .iter()
            .zip(opacities)
            .filter(|(m, o)| !(o.is_finite() && m.iter().all(|v| v.is_finite())))
            .count();
        Ok(non_finite)
    }

    /// Reduces the ray to pixel `(u, v)` at z-depth `d` to the motion plane.
    fn plane_ray(&self, origin: &Point3<f64>, end: &Point3<f64>, truncated: bool) -> PlaneRay {
        let (lo, hi) = self.band_z();
        let dz = end.z - origin.z;
        // Parameter interval [t0, t1] ⊂ [0, 1] where the ray's height lies in the band.
        let (mut t0, mut t1) = (0.0f64, 1.0f64);
        if dz.abs() < 1e-12 {
            if origin.z < lo || origin.z > hi {
                t1 = -1.0;
            }
        } else {
            let (ta, tb) = ((lo - origin.z) / dz, (hi - origin.z) / dz);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
        let at = |t: f64| {
            Point2::new(
                origin.x + t * (end.x - origin.x),
                origin.y + t * (end.y - origin.y),
            )
        };
        let end2 = Point2::new(end.x, end.y);
        let end_mark = if truncated {
            MARK_NONE
        } else if end.z >= lo && end.z <= hi {
            MARK_HIT
        } else if self.is_floor_z(end.z) {
            MARK_FREE
        } else {
            MARK_NONE
        };
        PlaneRay {
            band: (t0 <= t1).then(|| (at(t0), at(t1))),
            end: end2,
            end_mark,
        }
    }

    /// Integrates one depth image (z-depth in metres, row-major, 0 = no reading) taken by a
    /// camera with `intrinsics` at `t_world_camera`.
    pub fn integrate_depth(
        &mut self,
        depth: &[f32],
        intrinsics: &Intrinsics,
        t_world_camera: &Isometry3<f64>,
    ) -> Result<DepthUpdateStats, PlanningError> {
        let (w, h) = (intrinsics.width as usize, intrinsics.height as usize);
        if depth.len() != w * h {
            return Err(PlanningError::SizeMismatch {
                what: "depth image",
                expected: w * h,
                got: depth.len(),
            });
        }
        let pose_ok = t_world_camera
            .translation
            .vector
            .iter()
            .all(|v| v.is_finite())
            && t_world_camera.rotation.coords.iter().all(|v| v.is_finite());
        if !pose_ok {
            return Err(PlanningError::NonFinite {
                what: "camera pose",
            });
        }
        let k = [intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy];
        if !k.iter().all(|v| v.is_finite()) || intrinsics.fx == 0.0 || intrinsics.fy == 0.0 {
            return Err(PlanningError::NonFinite {
                what: "camera intrinsics",
            });
        }
        let origin = Point3::from(t_world_camera.translation.vector);
        let stride = self.config.pixel_stride;
        let max_depth = self.config.max_depth;
        let this = &*self;
        // Column-major order: a level camera's pixel column is one line on the plane, so the
        // rays of a line come out consecutively (see the merging below).
        let rays: Vec<PlaneRay> = (0..w)
            .into_par_iter()
            .step_by(stride)
            .flat_map_iter(|u| {
                let origin = &origin;
                (0..h).step_by(stride).filter_map(move |v| {
                    let d = depth[v * w + u] as f64;
                    if !(d.is_finite() && d > 0.0) {
                        return None;
                    }
                    let truncated = d > max_depth;
                    let pc = intrinsics.unproject(u as f64, v as f64, d.min(max_depth));
                    let end = t_world_camera * pc;
                    let ray = this.plane_ray(origin, &end, truncated);
                    this.within_limit(ray.end).then_some(ray)
                })
            })
            .collect();
        let mut lo = Point2::new(origin.x, origin.y);
        let mut hi = lo;
        for r in &rays {
            lo = lo.inf(&r.end);
            hi = hi.sup(&r.end);
        }
        self.ensure_contains(lo, hi)?;
        let g = *self.geometry();
        let mut touched: Vec<usize> = Vec::new();
        let mut stats = DepthUpdateStats::default();
        {
            let marks = &mut self.frame_mark;
            let mut mark = |cell: Cell, m: u8| {
                if let Some(i) = g.index(cell) {
                    if marks[i] == MARK_NONE {
                        touched.push(i);
                    }
                    marks[i] = marks[i].max(m);
                }
            };
            // Rays of one frame share the camera centre, so rays with the same azimuth (a
            // level camera's pixel column) are collinear on the plane: traverse the union of
            // their band intervals once per line instead of once per ray. Marks combine by
            // maximum, so this frees exactly the union of the cells each ray would free.
            let o2 = Point2::new(origin.x, origin.y);
            let mut lines: Vec<(i64, f64, f64, nalgebra::Vector2<f64>)> = Vec::new();
            for r in &rays {
                stats.rays += 1;
                if let Some((a, b)) = r.band {
                    let vb = b - o2;
                    let len = vb.norm();
                    if len < 1e-9 {
                        mark(g.cell_of(a), MARK_FREE);
                    } else {
                        let dir = vb / len;
                        let key = (dir.y.atan2(dir.x) * 1e7).round() as i64;
                        lines.push((key, (a - o2).dot(&dir).max(0.0), len, dir));
                    }
                }
            }
            // Runs of consecutive rays with the same azimuth key form one line: merge their
            // intervals (sorted by start) and traverse each merged interval once.
            let mut k = 0;
            let mut run: Vec<(f64, f64)> = Vec::new();
            while k < lines.len() {
                let (key, _, _, dir) = lines[k];
                run.clear();
                while k < lines.len() && lines[k].0 == key {
                    run.push((lines[k].1, lines[k].2));
                    k += 1;
                }
                run.sort_by(|a, b| a.0.total_cmp(&b.0));
                let (mut s0, mut s1) = run[0];
                for &(a, b) in &run[1..] {
                    if a <= s1 + 1e-9 {
                        s1 = s1.max(b);
                    } else {
                        for_each_ray_cell(&g, o2 + dir * s0, o2 + dir * s1, |c| mark(c, MARK_FREE));
                        (s0, s1) = (a, b);
                    }
                }
                for_each_ray_cell(&g, o2 + dir * s0, o2 + dir * s1, |c| mark(c, MARK_FREE));
            }
            for r in &rays {
                if r.end_mark != MARK_NONE {
                    stats.hits += usize::from(r.end_mark == MARK_HIT);
                    mark(g.cell_of(r.end), r.end_mark);
                }
            }
        }
        let (hit, miss, clamp) = (
            self.config.hit_log_odds,
            self.config.miss_log_odds,
            self.config.clamp_log_odds,
        );
        for &i in &touched {
            let delta = if self.frame_mark[i] == MARK_HIT {
                hit
            } else {
                -miss
            };
            self.log_odds.data[i] = (self.log_odds.data[i] + delta).clamp(-clamp, clamp);
            self.seen.data[i] = true;
            self.frame_mark[i] = MARK_NONE;
        }
        stats.cells_updated = touched.len();
        Ok(stats)
    }

    /// Marks the cell holding `center` and every cell whose centre lies within `radius` metres
    /// of it as surely free (the robot's own footprint, which the camera cannot see).
    pub fn mark_free_disc(
        &mut self,
        center: Point2<f64>,
        radius: f64,
    ) -> Result<(), PlanningError> {
        self.set_disc(center, radius, -self.config.clamp_log_odds)
    }

    /// Marks the cell holding `center` and every cell whose centre lies within `radius` metres
    /// of it as surely occupied (an obstacle inferred from a bump: too close or too low for
    /// the camera).
    pub fn mark_occupied_disc(
        &mut self,
        center: Point2<f64>,
        radius: f64,
    ) -> Result<(), PlanningError> {
        self.set_disc(center, radius, self.config.clamp_log_odds)
    }

    fn set_disc(
        &mut self,
        center: Point2<f64>,
        radius: f64,
        value: f32,
    ) -> Result<(), PlanningError> {
        if !(center.x.is_finite() && center.y.is_finite() && radius.is_finite() && radius >= 0.0) {
            return Err(PlanningError::NonFinite {
                what: "free disc centre or radius",
            });
        }
        let r = nalgebra::Vector2::new(radius, radius);
        self.ensure_contains(center - r, center + r)?;
        let g = *self.geometry();
        let (a, b) = (g.cell_of(center - r), g.cell_of(center + r));
        for y in a.y..=b.y {
            for x in a.x..=b.x {
                let c = Cell::new(x, y);
                if let Some(i) = g.index(c)
                    && ((g.center(c) - center).norm() <= radius || c == g.cell_of(center))
                {
                    self.log_odds.data[i] = value;
                    self.seen.data[i] = true;
                }
            }
        }
        Ok(())
    }

    /// The state of every cell before morphology: occupied when the map points exceed the
    /// threshold or the depth log-odds are positive; free when observed by rays or as floor.
    pub fn raw_grid(&self) -> OccupancyGrid {
        let g = *self.geometry();
        let data = (0..g.len())
            .map(|i| {
                let lo = self.log_odds.data[i];
                if self.band_points.data[i] > self.config.point_threshold
                    || (self.seen.data[i] && lo > 0.0)
                {
                    CellState::Occupied
                } else if self.seen.data[i]
                    || (self.config.floor_points_free && self.floor_points.data[i] > 0)
                {
                    CellState::Free
                } else {
                    CellState::Unknown
                }
            })
            .collect();
        Grid { geometry: g, data }
    }

    /// The occupancy grid: [`raw_grid`](Self::raw_grid) after the configured 3×3 opening.
    pub fn grid(&self) -> OccupancyGrid {
        let mut grid = self.raw_grid();
        let (w, h) = (grid.geometry.width, grid.geometry.height);
        match self.config.opening {
            OpeningTarget::None => {}
            OpeningTarget::Free => {
                let free: Vec<bool> = grid.data.iter().map(|s| *s == CellState::Free).collect();
                let kept = open3(&free, w, h);
                for (s, k) in grid.data.iter_mut().zip(kept) {
                    if *s == CellState::Free && !k {
                        *s = CellState::Unknown;
                    }
                }
            }
            OpeningTarget::Occupied => {
                let occ: Vec<bool> = grid
                    .data
                    .iter()
                    .map(|s| *s == CellState::Occupied)
                    .collect();
                let kept = open3(&occ, w, h);
                for (i, k) in kept.into_iter().enumerate() {
                    if grid.data[i] == CellState::Occupied && !k {
                        let observed = self.seen.data[i] || self.floor_points.data[i] > 0;
                        grid.data[i] = if observed {
                            CellState::Free
                        } else {
                            CellState::Unknown
                        };
                    }
                }
            }
        }
        grid
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_geometry::{PlanarPose, camera_pose_from_planar};
    use nalgebra::Vector3;

    /// Analytic depth (z-depth) of a scene made of the floor z = 0 and the wall plane
    /// x = `wall_x`, seen by `cam`; 0 where neither is hit within 20 m.
    fn wall_depth(k: &Intrinsics, cam: &Isometry3<f64>, wall_x: f64) -> Vec<f32> {
        let mut out = Vec::with_capacity(k.pixel_count());
        for v in 0..k.height {
            for u in 0..k.width {
                let rc = k.unproject(u as f64, v as f64, 1.0);
                let dir: Vector3<f64> = cam.rotation * rc.coords;
                let o = cam.translation.vector;
                let mut s = f64::INFINITY;
                if dir.x > 1e-12 {
                    s = s.min((wall_x - o.x) / dir.x);
                }
                if dir.z < -1e-12 {
                    s = s.min(-o.z / dir.z);
                }
                out.push(if s < 20.0 { s as f32 } else { 0.0 });
            }
        }
        out
    }

    fn mapper() -> OccupancyMapper {
        OccupancyMapper::new(
            OccupancyConfig::default(),
            Point2::new(-1.0, -3.0),
            Point2::new(3.0, 3.0),
        )
        .unwrap()
    }

    #[test]
    fn depth_of_a_known_wall_marks_the_right_cells() {
        let k = Intrinsics::from_hfov(160, 160, std::f64::consts::FRAC_PI_2);
        let cam = camera_pose_from_planar(&PlanarPose::new(0.0, 0.0, 0.0), 0.0, 0.88);
        // The wall plane sits mid-cell (cells are 5 cm from x = 0): column 40 covers [2.0, 2.05).
        let wall_x = 2.025;
        let depth = wall_depth(&k, &cam, wall_x);
        let mut m = mapper();
        let stats = m.integrate_depth(&depth, &k, &cam).unwrap();
        assert_eq!(stats.rays, 160 * 160);
        assert!(stats.hits > 0);
        let grid = m.grid();
        let g = grid.geometry;
        let state = |x: f64, y: f64| *grid.get(g.cell_of(Point2::new(x, y))).unwrap();
        // The wall: visible for |y| < 2.025 (45° half FOV), hits in the band at every column
        // row there; keep a margin of a few cells from the FOV edge.
        let mut y = -1.9;
        while y <= 1.9 {
            assert_eq!(state(wall_x, y), CellState::Occupied, "wall at y = {y}");
            // Just in front of the wall is free (band rays pass), behind it unknown.
            assert_eq!(
                state(wall_x - 0.1, y * 0.95),
                CellState::Free,
                "front at y = {y}"
            );
            assert_eq!(
                state(wall_x + 0.1, y),
                CellState::Unknown,
                "behind at y = {y}"
            );
            y += 0.05;
        }
        // Inside the view triangle (|y| < x·0.9) everything up to the wall is free; behind
        // the camera and outside the FOV stays unknown.
        for xi in 2..38 {
            let x = xi as f64 * 0.05 + 0.025;
            let half = x * 0.9 - 0.1;
            let mut y = -half;
            while y <= half {
                assert_eq!(state(x, y), CellState::Free, "({x}, {y}) should be free");
                y += 0.05;
            }
            assert_eq!(state(x, x * 1.1 + 0.15), CellState::Unknown);
            assert_eq!(state(x, -(x * 1.1 + 0.15)), CellState::Unknown);
        }
        assert_eq!(state(-0.5, 0.0), CellState::Unknown);
        // No occupied cell anywhere but the wall column.
        for i in 0..g.len() {
            if grid.data[i] == CellState::Occupied {
                assert_eq!(g.cell_at(i).x, g.cell_of(Point2::new(wall_x, 0.0)).x);
            }
        }
    }

    #[test]
    fn a_wall_beyond_max_depth_is_not_an_obstacle_and_the_grid_grows() {
        let k = Intrinsics::from_hfov(128, 128, std::f64::consts::FRAC_PI_2);
        let cam = camera_pose_from_planar(&PlanarPose::new(0.0, 0.0, 0.0), 0.0, 0.88);
        let depth = wall_depth(&k, &cam, 4.025);
        let mut m = OccupancyMapper::new(
            OccupancyConfig {
                max_depth: 3.0,
                ..Default::default()
            },
            Point2::new(-0.5, -0.5),
            Point2::new(0.5, 0.5),
        )
        .unwrap();
        m.integrate_depth(&depth, &k, &cam).unwrap();
        let grid = m.grid();
        assert!(
            grid.geometry
                .contains(grid.geometry.cell_of(Point2::new(2.9, 0.0)))
        );
        assert_eq!(grid.count(CellState::Occupied), 0);
        assert_eq!(
            grid.get(grid.geometry.cell_of(Point2::new(2.5, 0.0))),
            Some(&CellState::Free)
        );
    }

    #[test]
    fn map_points_occupy_above_the_threshold_and_only_in_the_band() {
        let mut m = mapper();
        let mut means = Vec::new();
        let mut opac = Vec::new();
        let mut put = |x: f32, y: f32, z: f32, n: usize, o: f32| {
            for _ in 0..n {
                means.push([x, y, z]);
                opac.push(o);
            }
        };
        put(0.525, 0.525, 0.5, 26, 0.9); // 26 > 25 in band: occupied
        put(1.025, 0.525, 0.5, 25, 0.9); // exactly 25: not occupied
        put(1.525, 0.525, 1.6, 40, 0.9); // above the band: ignored
        put(2.025, 0.525, 0.5, 40, 0.05); // transparent: ignored
        put(2.525, 0.525, 0.02, 3, 0.9); // floor: free
        put(8.025, 0.525, 0.5, 30, 0.9); // outside the initial bounds: grows, occupied
        m.set_map_points(&means, &opac).unwrap();
        let grid = m.grid();
        let g = grid.geometry;
        let s = |x: f64| *grid.get(g.cell_of(Point2::new(x, 0.525))).unwrap();
        assert_eq!(s(0.525), CellState::Occupied);
        assert_eq!(s(1.025), CellState::Unknown);
        assert_eq!(s(1.525), CellState::Unknown);
        assert_eq!(s(2.025), CellState::Unknown);
        assert_eq!(s(8.025), CellState::Occupied);
        // The single floor cell is free before the opening, removed by the free-space
        // opening (a 1-cell speck), kept without it.
        assert_eq!(
            *m.raw_grid()
                .get(g.cell_of(Point2::new(2.525, 0.525)))
                .unwrap(),
            CellState::Free
        );
        assert_eq!(s(2.525), CellState::Unknown);
        // Replacing the points replaces the counts.
        m.set_map_points(&[], &[]).unwrap();
        assert_eq!(m.grid().count(CellState::Occupied), 0);
        assert!(matches!(
            m.set_map_points(&[[0.0; 3]], &[]),
            Err(PlanningError::SizeMismatch { .. })
        ));
    }

    #[test]
    fn later_frames_clear_a_removed_obstacle_and_footprint_is_free() {
        let k = Intrinsics::from_hfov(64, 64, std::f64::consts::FRAC_PI_2);
        let cam = camera_pose_from_planar(&PlanarPose::new(0.0, 0.0, 0.0), 0.0, 0.88);
        let near = wall_depth(&k, &cam, 1.025);
        let far = wall_depth(&k, &cam, 2.525);
        let mut m = mapper();
        m.integrate_depth(&near, &k, &cam).unwrap();
        let at = |m: &OccupancyMapper, x: f64| {
            let g = m.grid();
            *g.get(g.geometry.cell_of(Point2::new(x, 0.0))).unwrap()
        };
        assert_eq!(at(&m, 1.025), CellState::Occupied);
        // One hit (+0.85) needs three passes (−0.4 each) to turn free.
        m.integrate_depth(&far, &k, &cam).unwrap();
        m.integrate_depth(&far, &k, &cam).unwrap();
        assert_eq!(at(&m, 1.025), CellState::Occupied);
        m.integrate_depth(&far, &k, &cam).unwrap();
        assert_eq!(at(&m, 1.025), CellState::Free);
        assert_eq!(at(&m, 2.525), CellState::Occupied);
        // The footprint disc, and a bump obstacle.
        m.mark_free_disc(Point2::new(-0.3, 0.0), 0.2).unwrap();
        assert_eq!(at(&m, -0.3), CellState::Free);
        m.mark_occupied_disc(Point2::new(-0.3, 0.0), 0.03).unwrap();
        assert_eq!(at(&m, -0.3), CellState::Occupied);
    }

    /// The per-line merging of collinear rays frees exactly the cells the plain per-ray DDA
    /// frees, on random views of a procedural house, level and tilted cameras.
    #[test]
    fn merged_rays_match_per_ray_traversal() {
        use crate::synthetic::SyntheticWorld;
        use activemap_geometry::UnitQuaternion;
        use rand::{Rng, SeedableRng};
        let world = SyntheticWorld::procedural_house(5, 2, 2, 3.0).unwrap();
        let k = Intrinsics::from_hfov(48, 40, 1.4);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let mut informative = 0;
        for trial in 0..12 {
            let p = PlanarPose::new(
                rng.random_range(0.5..5.5),
                rng.random_range(0.5..5.5),
                rng.random_range(-3.1..3.1),
            );
            let mut cam = camera_pose_from_planar(&p, 0.0, 0.88);
            if trial % 2 == 1 {
                let tilt = UnitQuaternion::from_euler_angles(0.05, -0.08, 0.0);
                cam.rotation *= tilt;
            }
            let depth = world.render_depth(&k, &cam);
            let mut m = mapper();
            m.integrate_depth(&depth, &k, &cam).unwrap();
            let got = m.raw_grid();
            let g = got.geometry;
            // Reference: every ray on its own.
            let mut marks = vec![MARK_NONE; g.len()];
            let origin = Point3::from(cam.translation.vector);
            for v in 0..k.height as usize {
                for u in 0..k.width as usize {
                    let d = depth[v * k.width as usize + u] as f64;
                    if d <= 0.0 {
                        continue;
                    }
                    let end = cam * k.unproject(u as f64, v as f64, d.min(5.0));
                    let r = m.plane_ray(&origin, &end, d > 5.0);
                    if let Some((a, b)) = r.band {
                        for_each_ray_cell(&g, a, b, |c| {
                            if let Some(i) = g.index(c) {
                                marks[i] = marks[i].max(MARK_FREE);
                            }
                        });
                    }
                    if let Some(i) = g.index(g.cell_of(r.end)) {
                        marks[i] = marks[i].max(r.end_mark);
                    }
                }
            }
            let mut differ = 0;
            for (i, mk) in marks.iter().enumerate() {
                let want = match *mk {
                    MARK_HIT => CellState::Occupied,
                    MARK_FREE => CellState::Free,
                    _ => CellState::Unknown,
                };
                if got.data[i] != want {
                    differ += 1;
                }
            }
            // Rays that merge across a quantisation step may shift a line by < 1e-6 m, which
            // can flip a cell whose border the ray grazes; allow a handful in a thousand.
            let touched = marks.iter().filter(|m| **m != MARK_NONE).count();
            informative += usize::from(touched >= 50);
            assert!(
                differ * 1000 <= touched,
                "trial {trial}: {differ} of {touched} cells differ"
            );
        }
        assert!(informative >= 8, "only {informative} views saw anything");
    }

    #[test]
    fn bad_depth_input_is_refused() {
        let k = Intrinsics::from_hfov(8, 8, 1.5);
        let cam = camera_pose_from_planar(&PlanarPose::new(0.0, 0.0, 0.0), 0.0, 0.88);
        let mut m = mapper();
        assert!(matches!(
            m.integrate_depth(&[1.0; 10], &k, &cam),
            Err(PlanningError::SizeMismatch {
                what: "depth image",
                ..
            })
        ));
        let mut bad = cam;
        bad.translation.vector.x = f64::NAN;
        assert!(matches!(
            m.integrate_depth(&[1.0; 64], &k, &bad),
            Err(PlanningError::NonFinite { .. })
        ));
        // NaN and negative depths are skipped, not errors.
        let mut d = vec![1.0f32; 64];
        d[3] = f32::NAN;
        d[4] = -1.0;
        assert_eq!(m.integrate_depth(&d, &k, &cam).unwrap().rays, 62);
        assert!(
            OccupancyMapper::new(
                OccupancyConfig {
                    band_min: 2.0,
                    ..Default::default()
                },
                Point2::origin(),
                Point2::new(1.0, 1.0)
            )
            .is_err()
        );
    }
    /// Bad numbers (issue 18): NaN / ±inf depth pixels cast no ray (a frame of them leaves the
    /// grid as it was; a fraction of them gives exactly the grid of the same pixels without a
    /// reading), a NaN pose or disc is refused with the grid untouched, and map points with a
    /// NaN / inf mean or opacity occupy nothing and are counted.
    #[test]
    fn non_finite_depth_points_and_poses_never_mark_a_cell() {
        use rand::{Rng, SeedableRng};
        let k = Intrinsics::from_hfov(64, 64, std::f64::consts::FRAC_PI_2);
        let cam = camera_pose_from_planar(&PlanarPose::new(0.0, 0.0, 0.0), 0.0, 0.88);
        let clean = wall_depth(&k, &cam, 2.025);
        let bad = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY];
        for b in bad {
            let mut m = mapper();
            let before = m.raw_grid();
            let stats = m.integrate_depth(&vec![b; clean.len()], &k, &cam).unwrap();
            assert_eq!(stats, DepthUpdateStats::default(), "depth {b}");
            assert_eq!(m.raw_grid(), before, "depth {b}");
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(18);
        let (mut holes, mut zeros) = (clean.clone(), clean.clone());
        for i in 0..clean.len() {
            if rng.random_bool(0.3) {
                holes[i] = bad[rng.random_range(0..3)];
                zeros[i] = 0.0;
            }
        }
        let (mut a, mut b) = (mapper(), mapper());
        let stats = a.integrate_depth(&holes, &k, &cam).unwrap();
        assert_eq!(stats, b.integrate_depth(&zeros, &k, &cam).unwrap());
        assert!(stats.hits > 0 && stats.rays < clean.len());
        assert_eq!(a.raw_grid(), b.raw_grid());
        // A NaN pose (translation or rotation) or disc: refused, nothing changes.
        let before = a.raw_grid();
        let mut nan_t = cam;
        nan_t.translation.vector.y = f64::NAN;
        let mut nan_q = cam;
        nan_q.rotation = nalgebra::UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(
            f64::NAN,
            0.0,
            0.0,
            0.0,
        ));
        for pose in [nan_t, nan_q] {
            let e = a.integrate_depth(&clean, &k, &pose).unwrap_err();
            assert_eq!(
                e,
                PlanningError::NonFinite {
                    what: "camera pose"
                }
            );
        }
        assert!(a.mark_free_disc(Point2::new(f64::NAN, 0.0), 0.2).is_err());
        assert!(
            a.mark_occupied_disc(Point2::new(0.0, 0.0), f64::INFINITY)
                .is_err()
        );
        assert_eq!(a.raw_grid(), before);
        // Map points: 30 good ones occupy their cell; 30 per kind of bad value elsewhere
        // occupy nothing and do not grow the grid.
        let mut m = mapper();
        let geometry = *m.geometry();
        let mut means = vec![[0.525f32, 0.525, 0.5]; 30];
        let mut opacities = vec![0.9f32; 30];
        for (mean, o) in [
            ([f32::NAN, 1.025, 0.5], 0.9),
            ([1.025, f32::INFINITY, 0.5], 0.9),
            ([1.025, 1.025, f32::NAN], 0.9),
            ([1.025, 1.025, 0.5], f32::NAN),
            ([1.525, 1.025, 0.5], f32::INFINITY),
        ] {
            means.extend(std::iter::repeat_n(mean, 30));
            opacities.extend(std::iter::repeat_n(o, 30));
        }
        assert_eq!(m.set_map_points(&means, &opacities).unwrap(), 150);
        assert_eq!(*m.geometry(), geometry);
        let raw = m.raw_grid();
        assert_eq!(raw.count(CellState::Occupied), 1);
        assert_eq!(
            raw.get(geometry.cell_of(Point2::new(0.525, 0.525))),
            Some(&CellState::Occupied)
        );
    }
}
