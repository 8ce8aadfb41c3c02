//! CPU RGB-D rasteriser: z-buffer, perspective-correct bilinear texturing, deferred shading.
//!
//! Per frame: vertices go to the camera frame (OpenCV optical, SPEC §2), triangles are clipped
//! against the near plane and projected with the pinhole of [`Intrinsics`] (pixel (i, j) samples
//! the image point u = i, v = j: the pixel-centre convention of `activemap_geometry::camera`).
//! Triangles are binned into bands of rows; each band is rasterised and shaded on its own
//! rayon task (the output does not depend on the number of threads). Visibility uses 1/z,
//! which is affine in screen space; the shading pass shades each pixel once from the winning
//! triangle with perspective-correct barycentrics. Triangles are double-sided and unlit.
//! Depth is z-depth in metres; 0 means no surface, or one beyond `max_depth`.

use crate::scene::{RepeatPow2Sampler, Scene};
use activemap_geometry::Intrinsics;
use nalgebra::Isometry3;
use rayon::prelude::*;

/// Rows per rasterisation band (the unit of parallel work).
const BAND_ROWS: usize = 16;
/// Triangles per setup task.
const SETUP_CHUNK: usize = 2048;
/// Inclusion tolerance on barycentrics so that pixel centres on shared edges are never missed.
const EDGE_EPS: f64 = 1e-7;

/// Clipping and range of the depth sensor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthRange {
    /// Near clipping plane, metres (> 0).
    pub near: f64,
    /// Readings beyond this z-depth are reported as 0 (no reading); colour still shows them.
    pub max_depth: f64,
}

impl Default for DepthRange {
    /// Habitat's depth sensor range: 0.01 m … 10 m.
    fn default() -> Self {
        Self {
            near: 0.01,
            max_depth: 10.0,
        }
    }
}

/// One rendered RGB-D frame.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbdFrame {
    /// The camera that produced it (image size and pinhole).
    pub intrinsics: Intrinsics,
    /// Colour, RGB8 interleaved, row-major from the top-left pixel (`3 × width × height` bytes).
    pub rgb: Vec<u8>,
    /// Z-depth in metres, row-major; 0 = no reading.
    pub depth: Vec<f32>,
}

impl RgbdFrame {
    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.intrinsics.width
    }
    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.intrinsics.height
    }
    /// Depth at pixel (x, y).
    pub fn depth_at(&self, x: u32, y: u32) -> f32 {
        self.depth[(y * self.intrinsics.width + x) as usize]
    }
    /// Colour at pixel (x, y).
    pub fn rgb_at(&self, x: u32, y: u32) -> [u8; 3] {
        let i = 3 * (y * self.intrinsics.width + x) as usize;
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }
}

/// A projected (possibly near-clipped) triangle ready for rasterisation and shading.
#[derive(Debug, Clone, Copy)]
struct ScreenTri {
    /// Barycentric k at pixel (x, y) = `edge[k][0]·x + edge[k][1]·y + edge[k][2]`.
    edge: [[f64; 3]; 3],
    /// 1/z at pixel (x, y) = `inv_z_plane[0]·x + inv_z_plane[1]·y + inv_z_plane[2]`.
    inv_z_plane: [f64; 3],
    /// Planes (same form) of `a/z` for the attributes a = (u, v, r, g, b), which are affine
    /// in screen space: dividing by 1/z gives perspective-correct values. Colours are
    /// pre-multiplied by the material's base colour (and by 255 when untextured).
    attr_planes: [[f64; 3]; 5],
    /// Inclusive pixel bounding box [x0, y0, x1, y1].
    bbox: [i32; 4],
    /// Texture index + 1 (0 = untextured).
    texture: u32,
}

/// A rasteriser holding reusable per-frame buffers (no allocation per frame once warm).
#[derive(Debug, Default)]
pub struct Renderer {
    camera_vertices: Vec<[f64; 3]>,
    /// Screen triangles of each setup chunk (kept for their capacity).
    chunk_tris: Vec<Vec<ScreenTri>>,
    /// All screen triangles of the frame, in scene order.
    tris: Vec<ScreenTri>,
    bins: Vec<Vec<u32>>,
    /// Per-pixel 1/z of the nearest surface so far.
    zbuf: Vec<f64>,
    /// Per-pixel index of the winning screen triangle (`u32::MAX` = none).
    ids: Vec<u32>,
}

/// A polygon vertex during near clipping: camera-frame position and original barycentrics.
#[derive(Clone, Copy)]
struct ClipVertex {
    p: [f64; 3],
    bary: [f32; 3],
}

fn clip_near(poly: &[ClipVertex], near: f64, out: &mut Vec<ClipVertex>) {
    out.clear();
    for i in 0..poly.len() {
        let a = poly[i];
        let b = poly[(i + 1) % poly.len()];
        let (ina, inb) = (a.p[2] >= near, b.p[2] >= near);
        if ina {
            out.push(a);
        }
        if ina != inb {
            let t = (near - a.p[2]) / (b.p[2] - a.p[2]);
            let tf = t as f32;
            out.push(ClipVertex {
                p: [
                    a.p[0] + t * (b.p[0] - a.p[0]),
                    a.p[1] + t * (b.p[1] - a.p[1]),
                    near,
                ],
                bary: std::array::from_fn(|k| a.bary[k] + tf * (b.bary[k] - a.bary[k])),
            });
        }
    }
}

/// Builds the screen triangle for three projected vertices; `None` when degenerate or
/// covering no pixel centre.
fn setup_screen_tri(
    v: [[f64; 3]; 3],
    attrs: [[f64; 5]; 3],
    texture: u32,
    width: i32,
    height: i32,
) -> Option<ScreenTri> {
    let (mut v, mut attrs) = (v, attrs);
    let area =
        (v[1][0] - v[0][0]) * (v[2][1] - v[0][1]) - (v[2][0] - v[0][0]) * (v[1][1] - v[0][1]);
    if !area.is_finite() || area.abs() < 1e-12 {
        return None;
    }
    if area < 0.0 {
        v.swap(1, 2);
        attrs.swap(1, 2);
    }
    let area = area.abs();
    let min_x = v.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min);
    let max_x = v.iter().map(|p| p[0]).fold(f64::NEG_INFINITY, f64::max);
    let min_y = v.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min);
    let max_y = v.iter().map(|p| p[1]).fold(f64::NEG_INFINITY, f64::max);
    let x0 = min_x.ceil().max(0.0);
    let y0 = min_y.ceil().max(0.0);
    let x1 = max_x.floor().min(width as f64 - 1.0);
    let y1 = max_y.floor().min(height as f64 - 1.0);
    if x0 > x1 || y0 > y1 {
        return None;
    }
    // Barycentric of vertex k: signed area of the opposite edge with the pixel, over `area`.
    let mut edge = [[0.0; 3]; 3];
    for (k, e) in edge.iter_mut().enumerate() {
        let a = v[(k + 1) % 3];
        let b = v[(k + 2) % 3];
        // (b − a) × (p − a) = (bx − ax)(py − ay) − (by − ay)(px − ax)
        e[0] = -(b[1] - a[1]) / area;
        e[1] = (b[0] - a[0]) / area;
        e[2] = ((b[1] - a[1]) * a[0] - (b[0] - a[0]) * a[1]) / area;
    }
    let inv_z = [v[0][2], v[1][2], v[2][2]];
    let inv_z_plane = std::array::from_fn(|c| (0..3).map(|k| edge[k][c] * inv_z[k]).sum());
    let attr_planes = std::array::from_fn(|a| {
        std::array::from_fn(|c| (0..3).map(|k| edge[k][c] * attrs[k][a] * inv_z[k]).sum())
    });
    Some(ScreenTri {
        edge,
        inv_z_plane,
        attr_planes,
        bbox: [x0 as i32, y0 as i32, x1 as i32, y1 as i32],
        texture,
    })
}

impl Renderer {
    /// A renderer with empty scratch buffers.
    pub fn new() -> Self {
        Self::default()
    }

    /// Renders `scene` seen by a camera with intrinsics `k` at `t_world_camera` into a new frame.
    pub fn render(
        &mut self,
        scene: &Scene,
        k: &Intrinsics,
        t_world_camera: &Isometry3<f64>,
        range: DepthRange,
    ) -> RgbdFrame {
        let n = k.width as usize * k.height as usize;
        let mut rgb = vec![0u8; 3 * n];
        let mut depth = vec![0f32; n];
        self.render_into(scene, k, t_world_camera, range, &mut rgb, &mut depth)
            .expect("buffers sized for the image");
        RgbdFrame {
            intrinsics: *k,
            rgb,
            depth,
        }
    }

    /// Renders into caller-owned buffers, e.g. a loaned shared-memory frame: `rgb` holds
    /// `3 × width × height` bytes (RGB8, row-major), `depth` `width × height` z-depths in metres
    /// (0 = no reading). Every element is written, whatever the buffers held before.
    pub fn render_into(
        &mut self,
        scene: &Scene,
        k: &Intrinsics,
        t_world_camera: &Isometry3<f64>,
        range: DepthRange,
        rgb: &mut [u8],
        depth: &mut [f32],
    ) -> crate::Result<()> {
        let (width, height) = (k.width as usize, k.height as usize);
        for (what, len, expected) in [
            ("rgb", rgb.len(), 3 * width * height),
            ("depth", depth.len(), width * height),
        ] {
            if len != expected {
                return Err(crate::SimError::RenderTarget {
                    what,
                    len,
                    expected,
                    width: k.width,
                    height: k.height,
                });
            }
        }
        if width == 0 || height == 0 {
            return Ok(());
        }
        let t_cw = t_world_camera.inverse();
        let (rot, tr) = (t_cw.rotation.to_rotation_matrix(), t_cw.translation.vector);
        let m = rot.matrix();
        scene
            .vertices
            .par_iter()
            .map(|v| {
                let p = v.position.map(|c| c as f64);
                std::array::from_fn(|r| {
                    m[(r, 0)] * p[0] + m[(r, 1)] * p[1] + m[(r, 2)] * p[2] + tr[r]
                })
            })
            .collect_into_vec(&mut self.camera_vertices);
        let cam = &self.camera_vertices;

        // Frustum half-spaces through the optical centre (the pixel area spans u ∈ [−0.5, w − 0.5]).
        let x_lo = (-0.5 - k.cx) / k.fx;
        let x_hi = (width as f64 - 0.5 - k.cx) / k.fx;
        let y_lo = (-0.5 - k.cy) / k.fy;
        let y_hi = (height as f64 - 0.5 - k.cy) / k.fy;
        let (x_lo, x_hi) = (x_lo.min(x_hi), x_lo.max(x_hi));
        let (y_lo, y_hi) = (y_lo.min(y_hi), y_lo.max(y_hi));
        let near = range.near;
        let identity: [[f32; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

        let n_chunks = scene.triangles.len().div_ceil(SETUP_CHUNK);
        self.chunk_tris.resize_with(n_chunks, Vec::new);
        scene
            .triangles
            .par_chunks(SETUP_CHUNK)
            .zip(self.chunk_tris.par_iter_mut())
            .for_each(|(chunk, out)| {
                out.clear();
                let mut poly = Vec::with_capacity(4);
                let mut clipped = Vec::with_capacity(4);
                for t in chunk {
                    let c = t.vertices.map(|vi| cam[vi as usize]);
                    if c.iter().all(|p| p[2] < near)
                        || c.iter().all(|p| p[0] < x_lo * p[2])
                        || c.iter().all(|p| p[0] > x_hi * p[2])
                        || c.iter().all(|p| p[1] < y_lo * p[2])
                        || c.iter().all(|p| p[1] > y_hi * p[2])
                    {
                        continue;
                    }
                    let material = &scene.materials[t.material as usize];
                    let texture = material.texture.map_or(0, |i| i + 1);
                    let colour_scale = if texture == 0 { 255.0 } else { 1.0 };
                    let corner_attrs: [[f64; 5]; 3] = t.vertices.map(|vi| {
                        let v = &scene.vertices[vi as usize];
                        let col =
                            |k: usize| (v.color[k] * material.base_color[k]) as f64 * colour_scale;
                        [v.uv[0] as f64, v.uv[1] as f64, col(0), col(1), col(2)]
                    });
                    let mix = |bary: [f32; 3]| -> [f64; 5] {
                        std::array::from_fn(|a| {
                            (0..3).map(|j| bary[j] as f64 * corner_attrs[j][a]).sum()
                        })
                    };
                    let project = |p: &[f64; 3]| {
                        let iz = 1.0 / p[2];
                        [k.fx * p[0] * iz + k.cx, k.fy * p[1] * iz + k.cy, iz]
                    };
                    if c.iter().all(|p| p[2] >= near) {
                        if let Some(st) = setup_screen_tri(
                            c.map(|p| project(&p)),
                            corner_attrs,
                            texture,
                            width as i32,
                            height as i32,
                        ) {
                            out.push(st);
                        }
                        continue;
                    }
                    poly.clear();
                    poly.extend((0..3).map(|j| ClipVertex {
                        p: c[j],
                        bary: identity[j],
                    }));
                    clip_near(&poly, near, &mut clipped);
                    for j in 1..clipped.len().saturating_sub(1) {
                        let corners = [clipped[0], clipped[j], clipped[j + 1]];
                        if let Some(st) = setup_screen_tri(
                            corners.map(|cv| project(&cv.p)),
                            corners.map(|cv| mix(cv.bary)),
                            texture,
                            width as i32,
                            height as i32,
                        ) {
                            out.push(st);
                        }
                    }
                }
            });
        self.tris.clear();
        for chunk in &self.chunk_tris[..n_chunks] {
            self.tris.extend_from_slice(chunk);
        }
        let tris = &self.tris;

        let n_bands = height.div_ceil(BAND_ROWS);
        self.bins.resize_with(n_bands, Vec::new);
        self.bins.iter_mut().for_each(Vec::clear);
        for (i, t) in tris.iter().enumerate() {
            let b0 = t.bbox[1] as usize / BAND_ROWS;
            let b1 = t.bbox[3] as usize / BAND_ROWS;
            for b in &mut self.bins[b0..=b1] {
                b.push(i as u32);
            }
        }

        self.zbuf.resize(width * height, 0.0);
        self.ids.resize(width * height, u32::MAX);
        let bins = &self.bins;
        rgb.par_chunks_mut(3 * width * BAND_ROWS)
            .zip(depth.par_chunks_mut(width * BAND_ROWS))
            .zip(self.zbuf.par_chunks_mut(width * BAND_ROWS))
            .zip(self.ids.par_chunks_mut(width * BAND_ROWS))
            .enumerate()
            .for_each(|(band, (((rgb_band, depth_band), zbuf), ids))| {
                let y_start = band * BAND_ROWS;
                let rows = depth_band.len() / width;
                zbuf.fill(0.0);
                ids.fill(u32::MAX);
                for &ti in &bins[band] {
                    rasterise(&tris[ti as usize], ti, y_start, rows, width, zbuf, ids);
                }
                for r in 0..rows {
                    let row = r * width;
                    let py = (y_start + r) as f64;
                    let mut x = 0;
                    while x < width {
                        let id = ids[row + x];
                        if id == u32::MAX {
                            // No surface: black, no depth reading.
                            rgb_band[3 * (row + x)..3 * (row + x) + 3].fill(0);
                            depth_band[row + x] = 0.0;
                            x += 1;
                            continue;
                        }
                        // A run of pixels won by the same triangle: shade it incrementally.
                        let mut end = x + 1;
                        while end < width && ids[row + end] == id {
                            end += 1;
                        }
                        let (rgb_run, depth_run) = (
                            &mut rgb_band[3 * (row + x)..3 * (row + end)],
                            &mut depth_band[row + x..row + end],
                        );
                        shade_run(
                            &scene.textures,
                            &tris[id as usize],
                            x as f64,
                            py,
                            range.max_depth,
                            rgb_run,
                            depth_run,
                        );
                        x = end;
                    }
                }
            });
        Ok(())
    }
}

/// Depth-tests one screen triangle over the rows of a band.
fn rasterise(
    st: &ScreenTri,
    id: u32,
    y_start: usize,
    rows: usize,
    width: usize,
    zbuf: &mut [f64],
    ids: &mut [u32],
) {
    let ry0 = (st.bbox[1] as usize).max(y_start);
    let ry1 = (st.bbox[3] as usize).min(y_start + rows - 1);
    for y in ry0..=ry1 {
        let yf = y as f64;
        let (mut lo, mut hi) = (st.bbox[0] as f64, st.bbox[2] as f64);
        for e in &st.edge {
            let rest = e[1] * yf + e[2] + EDGE_EPS;
            if e[0] > 0.0 {
                lo = lo.max(-rest / e[0]);
            } else if e[0] < 0.0 {
                hi = hi.min(-rest / e[0]);
            } else if rest < 0.0 {
                hi = -1.0;
            }
        }
        if lo > hi {
            continue;
        }
        let (xl, xr) = (lo.ceil() as usize, hi.floor() as isize);
        if xr < xl as isize {
            continue;
        }
        let row = (y - y_start) * width;
        let zx = st.inv_z_plane[0];
        let z_row = st.inv_z_plane[1] * yf + st.inv_z_plane[2];
        for x in xl..=xr as usize {
            let iz = zx * x as f64 + z_row;
            let i = row + x;
            if iz > zbuf[i] {
                zbuf[i] = iz;
                ids[i] = id;
            }
        }
    }
}

/// Shades the pixels `x0, x0 + 1, …` of row `py` (as many as `depth.len()`), all covered by
/// `st`: colour and z-depth from the screen-affine planes of 1/z and attribute/z, stepped by
/// their x-gradients. The texture path is chosen once per run, not per pixel.
#[inline]
fn shade_run(
    textures: &[crate::scene::Texture],
    st: &ScreenTri,
    x0: f64,
    py: f64,
    max_depth: f64,
    rgb: &mut [u8],
    depth: &mut [f32],
) {
    match (st.texture > 0).then(|| &textures[st.texture as usize - 1]) {
        None => shade_span::<false>(st, x0, py, max_depth, rgb, depth, |_, _| [1.0; 3]),
        Some(t) => match RepeatPow2Sampler::of(t) {
            Some(fast) => {
                shade_span::<true>(st, x0, py, max_depth, rgb, depth, |u, v| fast.sample(u, v))
            }
            None => shade_span::<true>(st, x0, py, max_depth, rgb, depth, |u, v| {
                t.sample_bilinear(u, v)
            }),
        },
    }
}

/// The per-pixel loop of [`shade_run`], specialised for textured or flat triangles.
#[inline(always)]
fn shade_span<const TEXTURED: bool>(
    st: &ScreenTri,
    x0: f64,
    py: f64,
    max_depth: f64,
    rgb: &mut [u8],
    depth: &mut [f32],
    sample: impl Fn(f32, f32) -> [f32; 3],
) {
    let plane = |p: &[f64; 3]| p[0] * x0 + p[1] * py + p[2];
    let a = &st.attr_planes;
    let mut inv_z = plane(&st.inv_z_plane);
    let mut attr = [
        plane(&a[0]),
        plane(&a[1]),
        plane(&a[2]),
        plane(&a[3]),
        plane(&a[4]),
    ];
    let d_inv_z = st.inv_z_plane[0];
    let d_attr = [a[0][0], a[1][0], a[2][0], a[3][0], a[4][0]];
    for (px, d) in rgb.chunks_exact_mut(3).zip(depth.iter_mut()) {
        let z = 1.0 / inv_z;
        let mut c = [
            (attr[2] * z) as f32,
            (attr[3] * z) as f32,
            (attr[4] * z) as f32,
        ];
        if TEXTURED {
            let s = sample((attr[0] * z) as f32, (attr[1] * z) as f32);
            c = [c[0] * s[0], c[1] * s[1], c[2] * s[2]];
        }
        px[0] = (c[0] + 0.5).clamp(0.0, 255.0) as u8;
        px[1] = (c[1] + 0.5).clamp(0.0, 255.0) as u8;
        px[2] = (c[2] + 0.5).clamp(0.0, 255.0) as u8;
        *d = if z <= max_depth { z as f32 } else { 0.0 };
        inv_z += d_inv_z;
        for (v, dv) in attr.iter_mut().zip(d_attr) {
            *v += dv;
        }
    }
}
