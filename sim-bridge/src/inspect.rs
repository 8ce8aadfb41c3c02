//! What a scene becomes once placed, without running an episode (`activemap scene inspect`):
//! the placement applied (with its report), the floor height, the navigable floor, its rooms
//! ([`NavigableMap::rooms`](crate::NavigableMap::rooms)) and a top-down picture of the placed
//! scene with the rooms tinted on its navigable floor.

use crate::error::{Result, SimError};
use crate::load::Loaded;
use crate::navigation::{AgentShape, Navigation, Rooms, estimate_floor_z};
use crate::{SceneSpec, SimConfig};
use std::path::Path;

/// Free space that marks a room, metres ([`NavigableMap::rooms`](crate::NavigableMap::rooms)):
/// an opening between two rooms narrower than about 2 m separates them.
pub const ROOM_CLEARANCE: f64 = 0.9;
/// Free space that marks a small room behind a door, metres: more than a doorway's (its
/// navigable width, after the robot's radius, is under 0.9 m).
pub const DOOR_CLEARANCE: f64 = 0.45;
/// Smallest marker of a room, m² (smaller ones are gaps between furniture).
pub const MIN_ROOM_CORE: f64 = 0.5;
/// How far above the floor the top-down view cuts the scene, metres: below most ceilings and
/// above furniture, so walls show as the cut's darkest lines.
pub const VIEW_CUT: f64 = 2.0;
/// Largest side of the top-down picture, pixels (a coarser pixel is used beyond).
pub const MAX_VIEW_SIDE: u32 = 4096;

/// A placed scene with its navigable floor and rooms ([`inspect`]).
#[derive(Debug)]
pub struct Inspection {
    /// The scene as placed, the loader's warnings and the placement report.
    pub loaded: Loaded,
    /// The floor height used: the configured one, the scene's own, else estimated, metres.
    pub floor_z: f64,
    /// The navigation the simulator would build (obstacles, navigable map).
    pub navigation: Navigation,
    /// The rooms of the navigable map.
    pub rooms: Rooms,
}

/// Loads and places the scene of `spec` and builds what the simulator with `config` would:
/// the floor height, the navigable map, and its rooms. No start pose is derived and nothing is
/// rendered, so a scene whose floor is not navigable still inspects (with an empty map).
pub fn inspect(spec: &SceneSpec, config: &SimConfig) -> Result<Inspection> {
    config.validate()?;
    let loaded = spec.load()?;
    let scene = &loaded.scene;
    let floor_z = config
        .floor_z
        .or(scene.floor_z)
        .or_else(|| estimate_floor_z(scene))
        .ok_or_else(|| SimError::NoNavigableArea(scene.name.clone()))?;
    let agent = AgentShape {
        radius: config.robot.radius_m,
        ..config.agent
    };
    let navigation = Navigation::build(scene, floor_z, agent, config.nav_cell_size)?;
    let rooms = navigation
        .map()
        .rooms(DOOR_CLEARANCE, ROOM_CLEARANCE, MIN_ROOM_CORE);
    Ok(Inspection {
        loaded,
        floor_z,
        navigation,
        rooms,
    })
}

/// The colour of room `k` in the top-down view (a fixed palette, repeating after 10 rooms).
pub fn room_colour(k: usize) -> [u8; 3] {
    const PALETTE: [[u8; 3]; 10] = [
        [230, 25, 75],
        [60, 180, 75],
        [0, 130, 200],
        [245, 130, 48],
        [145, 30, 180],
        [70, 240, 240],
        [240, 50, 230],
        [210, 245, 60],
        [0, 128, 128],
        [170, 110, 40],
    ];
    PALETTE[k % PALETTE.len()]
}

impl Inspection {
    /// The top-down view of the placed scene, `metres_per_pixel` a pixel (coarser if the
    /// picture would exceed [`MAX_VIEW_SIDE`]), +x to the right and +y up: the highest surface
    /// below the cut at [`VIEW_CUT`] above the floor, grey by height (floor light, walls dark at
    /// the cut), white where there is none; navigable cells tinted with their room's
    /// [`room_colour`] (navigable cells of no room in pale grey-blue).
    pub fn top_down(&self, metres_per_pixel: f64) -> Result<image::RgbImage> {
        if !(metres_per_pixel.is_finite() && metres_per_pixel > 0.0) {
            return Err(SimError::InvalidConfig {
                field: "metres_per_pixel",
                value: metres_per_pixel.to_string(),
                reason: "must be > 0",
            });
        }
        let scene = &self.loaded.scene;
        let bounds = scene
            .bounds()
            .ok_or_else(|| SimError::EmptyScene(scene.name.clone()))?;
        let (w_m, h_m) = (bounds.max.x - bounds.min.x, bounds.max.y - bounds.min.y);
        let side = w_m.max(h_m);
        let px = metres_per_pixel.max(side / (MAX_VIEW_SIDE - 1) as f64);
        let (w, h) = (
            ((w_m / px).ceil() as u32).max(1),
            ((h_m / px).ceil() as u32).max(1),
        );
        let cut = self.floor_z + VIEW_CUT;
        let below = self.floor_z - 0.05;
        // Highest surface height per pixel, row 0 at the top (largest y).
        let mut top = vec![f64::NEG_INFINITY; (w * h) as usize];
        let to_px = |x: f64, y: f64| ((x - bounds.min.x) / px, (bounds.max.y - y) / px);
        let mut mark = |i: i64, j: i64, z: f64| {
            if (0..w as i64).contains(&i) && (0..h as i64).contains(&j) {
                let t = &mut top[(j * w as i64 + i) as usize];
                *t = t.max(z);
            }
        };
        for t in &scene.triangles {
            let c = scene.corners(t);
            if c.iter().all(|p| p.z > cut) || c.iter().all(|p| p.z < below) {
                continue;
            }
            let z_top = c
                .iter()
                .map(|p| p.z)
                .fold(f64::NEG_INFINITY, f64::max)
                .min(cut);
            let q = c.map(|p| to_px(p.x, p.y));
            // The edges (a wall projects onto a line), then the inside.
            for k in 0..3 {
                let (a, b) = (q[k], q[(k + 1) % 3]);
                let steps = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
                for s in 0..=steps {
                    let f = s as f64 / steps as f64;
                    let (x, y) = (a.0 + f * (b.0 - a.0), a.1 + f * (b.1 - a.1));
                    mark(x.floor() as i64, y.floor() as i64, z_top);
                }
            }
            let area =
                (q[1].0 - q[0].0) * (q[2].1 - q[0].1) - (q[2].0 - q[0].0) * (q[1].1 - q[0].1);
            if area.abs() < 1e-9 {
                continue;
            }
            let (x0, x1) = (
                q.iter().map(|p| p.0).fold(f64::INFINITY, f64::min),
                q.iter().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max),
            );
            let (y0, y1) = (
                q.iter().map(|p| p.1).fold(f64::INFINITY, f64::min),
                q.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max),
            );
            for j in (y0.floor() as i64).max(0)..=(y1.ceil() as i64).min(h as i64 - 1) {
                for i in (x0.floor() as i64).max(0)..=(x1.ceil() as i64).min(w as i64 - 1) {
                    let (x, y) = (i as f64 + 0.5, j as f64 + 0.5);
                    let l1 = ((q[1].0 - x) * (q[2].1 - y) - (q[2].0 - x) * (q[1].1 - y)) / area;
                    let l2 = ((q[2].0 - x) * (q[0].1 - y) - (q[0].0 - x) * (q[2].1 - y)) / area;
                    let l3 = 1.0 - l1 - l2;
                    if l1 >= 0.0 && l2 >= 0.0 && l3 >= 0.0 {
                        let z = (l1 * c[0].z + l2 * c[1].z + l3 * c[2].z).min(cut);
                        mark(i, j, z);
                    }
                }
            }
        }
        let map = self.navigation.map();
        let mut image = image::RgbImage::new(w, h);
        for (j, row) in top.chunks(w as usize).enumerate() {
            for (i, z) in row.iter().enumerate() {
                let mut rgb = if z.is_finite() {
                    let v = ((z - self.floor_z) / VIEW_CUT).clamp(0.0, 1.0);
                    [(235.0 - 185.0 * v) as u8; 3]
                } else {
                    [255; 3]
                };
                let x = bounds.min.x + (i as f64 + 0.5) * px;
                let y = bounds.max.y - (j as f64 + 0.5) * px;
                if let Some((ci, cj)) = map.frame.cell_of(x, y)
                    && map.is_navigable(ci, cj)
                {
                    let l = self.rooms.label[cj * map.frame.width + ci];
                    let tint = if l == u32::MAX {
                        [180, 190, 210]
                    } else {
                        room_colour(l as usize)
                    };
                    for (c, t) in rgb.iter_mut().zip(tint) {
                        *c = ((*c as u16 + t as u16) / 2) as u8;
                    }
                }
                image.put_pixel(i as u32, j as u32, image::Rgb(rgb));
            }
        }
        Ok(image)
    }

    /// Writes [`Inspection::top_down`] as a PNG at `path`; returns its size in pixels.
    pub fn write_top_down(&self, path: &Path, metres_per_pixel: f64) -> Result<(u32, u32)> {
        let image = self.top_down(metres_per_pixel)?;
        image
            .save_with_format(path, image::ImageFormat::Png)
            .map_err(|e| SimError::Write {
                path: path.to_path_buf(),
                reason: e.to_string(),
            })?;
        Ok(image.dimensions())
    }
}
