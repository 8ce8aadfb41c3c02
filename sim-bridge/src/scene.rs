//! The in-memory scene: an indexed triangle mesh in the world frame (z up, metres) with
//! per-vertex texture coordinates and colours, per-triangle materials and RGB textures.
//!
//! Colours are display values in [0, 1] (no linear/sRGB conversion is applied anywhere), and
//! surfaces are unlit: a pixel's colour is `material.base_color × texture(uv) × vertex colour`,
//! as Habitat renders scanned meshes with baked lighting.

use activemap_geometry::PlanarPose;
use nalgebra::{Point3, Vector3};

/// One mesh vertex.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vertex {
    /// World position, metres (z up).
    pub position: [f32; 3],
    /// Texture coordinates; (0, 0) is the top-left corner of the image, v grows downwards.
    pub uv: [f32; 2],
    /// Vertex colour (RGB, display values in [0, 1]); white when the file has none.
    pub color: [f32; 3],
}

/// A triangle: three vertex indices and the material that paints it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Triangle {
    /// Indices into [`Scene::vertices`].
    pub vertices: [u32; 3],
    /// Index into [`Scene::materials`].
    pub material: u32,
}

/// How texture coordinates outside [0, 1] are mapped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Wrap {
    /// Tile the texture (glTF default).
    #[default]
    Repeat,
    /// Clamp to the border texel.
    ClampToEdge,
    /// Tile with every other copy mirrored.
    MirroredRepeat,
}

/// An RGB8 texture image, row-major from the top-left texel.
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    /// Where it came from (file name, glTF image index or generator name), for messages.
    pub name: String,
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// `width × height` texels.
    pub texels: Vec<[u8; 3]>,
    /// Wrap mode along u.
    pub wrap_u: Wrap,
    /// Wrap mode along v.
    pub wrap_v: Wrap,
}

#[inline]
fn wrap_index(i: i32, n: i32, wrap: Wrap) -> i32 {
    if (0..n).contains(&i) {
        return i;
    }
    match wrap {
        Wrap::Repeat => i.rem_euclid(n),
        Wrap::ClampToEdge => i.clamp(0, n - 1),
        Wrap::MirroredRepeat => {
            let m = i.rem_euclid(2 * n);
            if m < n { m } else { 2 * n - 1 - m }
        }
    }
}

impl Texture {
    /// Bilinear sample at texture coordinates (u, v), texel centres at `(i + 0.5) / width`.
    /// Returns RGB in [0, 255].
    #[inline]
    pub fn sample_bilinear(&self, u: f32, v: f32) -> [f32; 3] {
        let (w, h) = (self.width as i32, self.height as i32);
        let x = u * w as f32 - 0.5;
        let y = v * h as f32 - 0.5;
        // Keep the coordinates in a range where i32 conversion is exact.
        let x = if x.is_finite() {
            x.clamp(-1.0e6, 1.0e6)
        } else {
            0.0
        };
        let y = if y.is_finite() {
            y.clamp(-1.0e6, 1.0e6)
        } else {
            0.0
        };
        let xf = fast_floor(x);
        let yf = fast_floor(y);
        let (fx, fy) = (x - xf, y - yf);
        let (x0, y0) = (xf as i32, yf as i32);
        let (xa, xb, ya, yb) = if self.wrap_u == Wrap::Repeat
            && self.wrap_v == Wrap::Repeat
            && (w & (w - 1)) == 0
            && (h & (h - 1)) == 0
        {
            // Power-of-two tiling: wrap with a mask (two's complement handles negatives).
            let (mw, mh) = (w - 1, h - 1);
            (
                (x0 & mw) as usize,
                ((x0 + 1) & mw) as usize,
                (y0 & mh) as usize * w as usize,
                ((y0 + 1) & mh) as usize * w as usize,
            )
        } else {
            (
                wrap_index(x0, w, self.wrap_u) as usize,
                wrap_index(x0 + 1, w, self.wrap_u) as usize,
                wrap_index(y0, h, self.wrap_v) as usize * w as usize,
                wrap_index(y0 + 1, h, self.wrap_v) as usize * w as usize,
            )
        };
        let (t00, t10) = (self.texels[ya + xa], self.texels[ya + xb]);
        let (t01, t11) = (self.texels[yb + xa], self.texels[yb + xb]);
        let mut out = [0.0f32; 3];
        for c in 0..3 {
            let top = t00[c] as f32 + (t10[c] as f32 - t00[c] as f32) * fx;
            let bottom = t01[c] as f32 + (t11[c] as f32 - t01[c] as f32) * fx;
            out[c] = top + (bottom - top) * fy;
        }
        out
    }
}

/// Bilinear sampling of a power-of-two texture that repeats along both axes: wrapping is a
/// bit mask and the texel index is in range by construction, so the hot shading loop needs no
/// wrap branches and no bounds checks. Same arithmetic, hence the same bits, as
/// [`Texture::sample_bilinear`].
#[derive(Debug, Clone, Copy)]
pub(crate) struct RepeatPow2Sampler<'a> {
    texels: &'a [[u8; 3]],
    width: f32,
    height: f32,
    mask_x: i32,
    mask_y: i32,
    row_shift: u32,
}

impl<'a> RepeatPow2Sampler<'a> {
    /// The fast sampler of `t`, when it is a repeating power-of-two texture of consistent size.
    pub(crate) fn of(t: &'a Texture) -> Option<Self> {
        let pow2 = |n: u32| n > 0 && n.is_power_of_two() && n <= 1 << 15;
        (t.wrap_u == Wrap::Repeat
            && t.wrap_v == Wrap::Repeat
            && pow2(t.width)
            && pow2(t.height)
            && t.texels.len() == (t.width as usize) * (t.height as usize))
            .then(|| Self {
                texels: &t.texels,
                width: t.width as f32,
                height: t.height as f32,
                mask_x: t.width as i32 - 1,
                mask_y: t.height as i32 - 1,
                row_shift: t.width.trailing_zeros(),
            })
    }

    /// As [`Texture::sample_bilinear`]: RGB in [0, 255] at (u, v).
    #[inline(always)]
    pub(crate) fn sample(&self, u: f32, v: f32) -> [f32; 3] {
        let x = u * self.width - 0.5;
        let y = v * self.height - 0.5;
        let x = if x.is_finite() {
            x.clamp(-1.0e6, 1.0e6)
        } else {
            0.0
        };
        let y = if y.is_finite() {
            y.clamp(-1.0e6, 1.0e6)
        } else {
            0.0
        };
        let xf = fast_floor(x);
        let yf = fast_floor(y);
        let (fx, fy) = (x - xf, y - yf);
        let (x0, y0) = (xf as i32, yf as i32);
        let xa = (x0 & self.mask_x) as usize;
        let xb = ((x0 + 1) & self.mask_x) as usize;
        let ya = ((y0 & self.mask_y) as usize) << self.row_shift;
        let yb = (((y0 + 1) & self.mask_y) as usize) << self.row_shift;
        // SAFETY: x indices are masked below `width` and y indices below `height`, and `of`
        // checked `texels.len() == width × height` with width = 1 << row_shift, so every index
        // y·width + x is below the length.
        let (t00, t10, t01, t11) = unsafe {
            (
                *self.texels.get_unchecked(ya + xa),
                *self.texels.get_unchecked(ya + xb),
                *self.texels.get_unchecked(yb + xa),
                *self.texels.get_unchecked(yb + xb),
            )
        };
        let mut out = [0.0f32; 3];
        for c in 0..3 {
            let top = t00[c] as f32 + (t10[c] as f32 - t00[c] as f32) * fx;
            let bottom = t01[c] as f32 + (t11[c] as f32 - t01[c] as f32) * fx;
            out[c] = top + (bottom - top) * fy;
        }
        out
    }
}

/// `x.floor()` without a libm call (x within ±1e6).
#[inline]
fn fast_floor(x: f32) -> f32 {
    let t = x as i32 as f32;
    if t > x { t - 1.0 } else { t }
}

/// Surface appearance of a group of triangles.
#[derive(Debug, Clone, PartialEq)]
pub struct Material {
    /// Name from the file (or generator), for messages.
    pub name: String,
    /// Base colour factor, RGB in [0, 1].
    pub base_color: [f32; 3],
    /// Index into [`Scene::textures`], if textured.
    pub texture: Option<u32>,
}

/// A triangle-mesh scene in the world frame (z up, metres).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Scene {
    /// Where it came from (file path or generator), for messages.
    pub name: String,
    /// Mesh vertices.
    pub vertices: Vec<Vertex>,
    /// Mesh triangles.
    pub triangles: Vec<Triangle>,
    /// Materials referenced by the triangles.
    pub materials: Vec<Material>,
    /// Textures referenced by the materials.
    pub textures: Vec<Texture>,
    /// Floor height (world z) if the scene states it; otherwise derived from the mesh.
    pub floor_z: Option<f64>,
    /// Start pose if the scene states it; otherwise derived from the navigable area.
    pub start: Option<PlanarPose>,
}

/// Axis-aligned bounding box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// Minimum corner.
    pub min: Point3<f64>,
    /// Maximum corner.
    pub max: Point3<f64>,
}

impl Scene {
    /// The world position of vertex `i`, in f64.
    pub fn position(&self, i: u32) -> Point3<f64> {
        let p = self.vertices[i as usize].position;
        Point3::new(p[0] as f64, p[1] as f64, p[2] as f64)
    }

    /// The three corners of triangle `t`.
    pub fn corners(&self, t: &Triangle) -> [Point3<f64>; 3] {
        [
            self.position(t.vertices[0]),
            self.position(t.vertices[1]),
            self.position(t.vertices[2]),
        ]
    }

    /// Area-weighted normal of a triangle: `(b − a) × (c − a)`, length = twice the area.
    pub fn scaled_normal(&self, t: &Triangle) -> Vector3<f64> {
        let [a, b, c] = self.corners(t);
        (b - a).cross(&(c - a))
    }

    /// Bounding box of all vertices referenced by triangles; `None` for an empty scene.
    pub fn bounds(&self) -> Option<Aabb> {
        let mut it = self.triangles.iter().flat_map(|t| t.vertices);
        let first = self.position(it.next()?);
        let (mut min, mut max) = (first, first);
        for i in it {
            let p = self.position(i);
            min = min.inf(&p);
            max = max.sup(&p);
        }
        Some(Aabb { min, max })
    }

    /// Total surface area, m².
    pub fn surface_area(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| 0.5 * self.scaled_normal(t).norm())
            .sum()
    }

    /// Checks the internal references (vertex, material and texture indices, texture sizes).
    pub fn validate(&self) -> crate::Result<()> {
        let bad = |reason: String| crate::SimError::Malformed {
            format: "scene",
            path: self.name.clone().into(),
            reason,
        };
        if self.triangles.is_empty() {
            return Err(crate::SimError::EmptyScene(self.name.clone()));
        }
        let nv = self.vertices.len() as u32;
        for (i, t) in self.triangles.iter().enumerate() {
            if t.vertices.iter().any(|&v| v >= nv) {
                return Err(bad(format!("triangle {i} references a vertex >= {nv}")));
            }
            if t.material as usize >= self.materials.len() {
                return Err(bad(format!(
                    "triangle {i} references missing material {}",
                    t.material
                )));
            }
        }
        for m in &self.materials {
            if let Some(ti) = m.texture
                && ti as usize >= self.textures.len()
            {
                return Err(bad(format!(
                    "material {} references missing texture {ti}",
                    m.name
                )));
            }
        }
        for t in &self.textures {
            if t.width == 0 || t.height == 0 || t.texels.len() != (t.width * t.height) as usize {
                return Err(bad(format!("texture {} has inconsistent size", t.name)));
            }
        }
        if self
            .vertices
            .iter()
            .any(|v| v.position.iter().any(|c| !c.is_finite()))
        {
            return Err(bad("a vertex position is not finite".into()));
        }
        Ok(())
    }

    /// A 64-bit FNV-1a hash of the triangle soup as drawn: for each material in order, its
    /// colour and texture texels, then its triangles in order with their three corners
    /// (position, uv, colour). Independent of vertex indexing, so a scene and its GLB export
    /// (which regroups vertices by material) hash the same.
    pub fn content_hash(&self) -> u64 {
        let mut h = Fnv::new();
        h.u64(self.materials.len() as u64);
        for (mi, m) in self.materials.iter().enumerate() {
            m.base_color.iter().for_each(|c| h.f32(*c));
            match m.texture.map(|t| &self.textures[t as usize]) {
                Some(t) => {
                    h.u64(t.width as u64);
                    h.u64(t.height as u64);
                    t.texels.iter().for_each(|px| h.bytes(px));
                }
                None => h.u64(u64::MAX),
            }
            for t in self.triangles.iter().filter(|t| t.material as usize == mi) {
                for &vi in &t.vertices {
                    let v = &self.vertices[vi as usize];
                    v.position
                        .iter()
                        .chain(&v.uv)
                        .chain(&v.color)
                        .for_each(|c| h.f32(*c));
                }
            }
        }
        h.finish()
    }

    /// The same surface with every triangle split into four (edge midpoints) `levels` times;
    /// used to build benchmark scenes of a given triangle count.
    pub fn subdivided(&self, levels: u32) -> Scene {
        let mut out = self.clone();
        for _ in 0..levels {
            let mut vertices = Vec::with_capacity(out.triangles.len() * 6);
            let mut triangles = Vec::with_capacity(out.triangles.len() * 4);
            for t in &out.triangles {
                let [a, b, c] = t.vertices.map(|i| out.vertices[i as usize]);
                let mid = |p: &Vertex, q: &Vertex| Vertex {
                    position: std::array::from_fn(|k| 0.5 * (p.position[k] + q.position[k])),
                    uv: std::array::from_fn(|k| 0.5 * (p.uv[k] + q.uv[k])),
                    color: std::array::from_fn(|k| 0.5 * (p.color[k] + q.color[k])),
                };
                let (ab, bc, ca) = (mid(&a, &b), mid(&b, &c), mid(&c, &a));
                let base = vertices.len() as u32;
                vertices.extend_from_slice(&[a, b, c, ab, bc, ca]);
                for idx in [[0, 3, 5], [3, 1, 4], [5, 4, 2], [3, 4, 5]] {
                    triangles.push(Triangle {
                        vertices: idx.map(|k| base + k),
                        material: t.material,
                    });
                }
            }
            out.vertices = vertices;
            out.triangles = triangles;
        }
        out
    }
}

/// 64-bit FNV-1a, a fixed, platform-independent hash for determinism checks.
pub(crate) struct Fnv(u64);

impl Fnv {
    pub(crate) fn new() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
    pub(crate) fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 ^= x as u64;
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    pub(crate) fn u64(&mut self, x: u64) {
        self.bytes(&x.to_le_bytes());
    }
    /// Hashes a float with −0.0 folded into +0.0 (they compare equal).
    pub(crate) fn f32(&mut self, x: f32) {
        self.bytes(&(x + 0.0).to_le_bytes());
    }
    pub(crate) fn finish(&self) -> u64 {
        self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn checker() -> Texture {
        Texture {
            name: "checker".into(),
            width: 2,
            height: 2,
            texels: vec![[0, 0, 0], [200, 0, 0], [0, 100, 0], [0, 0, 50]],
            wrap_u: Wrap::Repeat,
            wrap_v: Wrap::ClampToEdge,
        }
    }

    #[test]
    fn bilinear_hits_texel_centres_and_midpoints() {
        let t = checker();
        // Texel (1, 0) centre is at u = 0.75, v = 0.25.
        assert_eq!(t.sample_bilinear(0.75, 0.25), [200.0, 0.0, 0.0]);
        // Midway between the four centres: the mean of the four texels.
        assert_eq!(t.sample_bilinear(0.5, 0.5), [50.0, 25.0, 12.5]);
        // Repeat along u: u = 1.75 is texel column 1 again.
        assert_eq!(t.sample_bilinear(1.75, 0.25), [200.0, 0.0, 0.0]);
        // Clamp along v: far below the image stays on the last row.
        assert_eq!(t.sample_bilinear(0.25, 9.0), [0.0, 100.0, 0.0]);
    }

    #[test]
    fn pow2_sampler_matches_the_general_sampler_bit_for_bit() {
        let mut t = checker();
        t.wrap_v = Wrap::Repeat;
        t.width = 4;
        t.height = 2;
        t.texels = (0..8u8).map(|i| [i * 30, 255 - i * 20, i * i]).collect();
        let fast = RepeatPow2Sampler::of(&t).expect("4×2 repeating texture");
        for i in -40..40 {
            for j in -13..17 {
                let (u, v) = (i as f32 * 0.071 + 0.003, j as f32 * 0.113 - 0.02);
                assert_eq!(fast.sample(u, v), t.sample_bilinear(u, v), "at ({u}, {v})");
            }
        }
        assert_eq!(fast.sample(f32::NAN, 0.3), t.sample_bilinear(f32::NAN, 0.3));
        assert_eq!(fast.sample(1e30, -1e30), t.sample_bilinear(1e30, -1e30));
        // Not applicable: clamped wrap, non-power-of-two size, inconsistent texel count.
        assert!(RepeatPow2Sampler::of(&checker()).is_none());
        t.width = 3;
        assert!(RepeatPow2Sampler::of(&t).is_none());
        t.width = 4;
        t.texels.pop();
        assert!(RepeatPow2Sampler::of(&t).is_none());
    }

    #[test]
    fn mirrored_wrap_reflects() {
        assert_eq!(wrap_index(-1, 4, Wrap::MirroredRepeat), 0);
        assert_eq!(wrap_index(4, 4, Wrap::MirroredRepeat), 3);
        assert_eq!(wrap_index(5, 4, Wrap::Repeat), 1);
        assert_eq!(wrap_index(-3, 4, Wrap::ClampToEdge), 0);
    }
}
