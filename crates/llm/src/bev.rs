//! The bird's-eye view (BEV) of the 3DGS map that the LLM planner sees (SPEC §7): top-down at
//! floor-plan scale, the ceiling removed, white background, cropped to the mapped area and
//! annotated as in the paper: the robot as a blue star at its estimated pose (its leading tip
//! and a short tick along its heading), the visited path as green lines, the last chosen
//! frontier as a yellow diamond and each candidate frontier `i` as a red number `i` centred on
//! the point the caller gives (the frontier cell nearest the region's centroid, as the
//! authors' release).
//!
//! Stages, each callable and testable alone:
//! 1. [`bev_window`]: the world rectangle, the (trimmed) extent of the drawn Gaussians' means
//!    together with every annotated point, plus [`BevConfig::margin_m`] and room for the marks,
//!    scaled so that the long side is [`BevConfig::long_side_px`];
//! 2. [`render_map`]: the orthographic splat render ([`activemap_splat::ortho`]) of the
//!    Gaussians whose mean lies below the camera height and whose largest scale is at most
//!    [`BevConfig::max_gaussian_size_m`] (the paper's 0.1 m), without unknown-space Gaussians;
//! 3. [`annotate`]: the marks, anti-aliased with tiny-skia, the digits as outlines of the
//!    bundled DejaVu Sans Bold (`assets/fonts`, Bitstream Vera licence) with a white halo so
//!    that they read on any background; drawn in the order path, diamond, star, numbers;
//! 4. [`Bev::png`]: PNG encoding (fast deflate, deterministic bytes).
//!
//! [`render_bev`] runs them all.
//!
//! Difference to the authors' release: they render a perspective view from 10 m above the map
//! centre and crop the non-white area; here the view is orthographic, so one pixel is the same
//! number of metres everywhere (walls do not lean outwards), and the crop is computed from the
//! map and the marks instead of searched in the image.
//!
//! Pixel coordinates (`[column, row]`, row 0 at the top = largest world y) put pixel centres at
//! integers, as the splat renderer; image right is world +x, image up is world +y.

use ab_glyph::{Font, FontRef, GlyphId, OutlineCurve};
use activemap_splat::ortho::{
    DEFAULT_LONG_SIDE_PX, DEFAULT_TRIM_FRACTION, OrthoImage, OrthoOptions, OrthoWindow, Selection,
    mean_bounds, render_ortho,
};
use activemap_splat::{FLAG_UNKNOWN_SPACE, Gaussians, SplatError};
use serde::{Deserialize, Serialize};
use tiny_skia::{FillRule, LineCap, LineJoin, Paint, Path, PathBuilder, Pixmap, Stroke, Transform};

use crate::error::LlmError;

/// The bundled font of the numbers: DejaVu Sans Bold (`assets/fonts/LICENSE-DejaVu.txt`).
static FONT_TTF: &[u8] = include_bytes!("../../../assets/fonts/DejaVuSans-Bold.ttf");

/// Colour of the visited path.
pub const PATH_RGB: [u8; 3] = [0, 170, 0];
/// Colour of the robot star.
pub const ROBOT_RGB: [u8; 3] = [0, 64, 255];
/// Fill of the last chosen frontier's diamond.
pub const FRONTIER_RGB: [u8; 3] = [255, 210, 0];
/// Outline of the diamond.
pub const FRONTIER_OUTLINE_RGB: [u8; 3] = [90, 70, 0];
/// Colour of the candidate numbers.
pub const LABEL_RGB: [u8; 3] = [220, 0, 0];
/// Colour of the halo around the numbers and the outline of the star.
pub const HALO_RGB: [u8; 3] = [255, 255, 255];

/// How the BEV is drawn (the `bev:` block of the planner's `llm:` settings). The ceiling cut
/// is not here: it is the camera height passed to [`render_bev`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BevConfig {
    /// Pixels of the image's long side (the paper: 800).
    pub long_side_px: u32,
    /// Largest Gaussian drawn: its largest per-axis scale, metres (the release: 0.1).
    pub max_gaussian_size_m: f64,
    /// World margin around the map and the marks, metres.
    pub margin_m: f64,
    /// Em size of the numbers' font, pixels (28 px: digits about 20 px tall).
    pub label_px: f32,
    /// Width of the white halo around each number's outline, pixels.
    pub label_halo_px: f32,
    /// Outer radius of the robot star, pixels.
    pub star_radius_px: f32,
    /// Half diagonal of the frontier diamond, pixels.
    pub diamond_radius_px: f32,
    /// Width of the path lines, pixels.
    pub path_width_px: f32,
}

impl Default for BevConfig {
    fn default() -> Self {
        Self {
            long_side_px: DEFAULT_LONG_SIDE_PX as u32,
            max_gaussian_size_m: 0.1,
            margin_m: 0.5,
            label_px: 28.0,
            label_halo_px: 3.0,
            star_radius_px: 14.0,
            diamond_radius_px: 12.0,
            path_width_px: 3.0,
        }
    }
}

/// Longest side accepted, pixels.
const MAX_LONG_SIDE_PX: u32 = 8192;

impl BevConfig {
    /// Checks every field, naming the first bad one.
    pub fn validate(&self) -> Result<(), LlmError> {
        self.check().map_err(|e| LlmError::Config(e.to_string()))
    }

    fn check(&self) -> Result<(), BevError> {
        let bad = |field: &'static str, message: String| Err(BevError::Config { field, message });
        if !(64..=MAX_LONG_SIDE_PX).contains(&self.long_side_px) {
            return bad(
                "long_side_px",
                format!("{} is outside 64..={MAX_LONG_SIDE_PX}", self.long_side_px),
            );
        }
        let positive = [
            ("max_gaussian_size_m", self.max_gaussian_size_m),
            ("label_px", self.label_px as f64),
            ("star_radius_px", self.star_radius_px as f64),
            ("diamond_radius_px", self.diamond_radius_px as f64),
            ("path_width_px", self.path_width_px as f64),
        ];
        let non_negative = [
            ("margin_m", self.margin_m),
            ("label_halo_px", self.label_halo_px as f64),
        ];
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return bad(field, format!("{v} must be finite and positive"));
            }
        }
        for (field, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return bad(field, format!("{v} must be finite and non-negative"));
            }
        }
        let largest_mark = [
            self.star_radius_px,
            self.diamond_radius_px,
            self.label_px + self.label_halo_px,
        ]
        .into_iter()
        .fold(0.0, f32::max);
        if largest_mark * 8.0 > self.long_side_px as f32 {
            return bad(
                "long_side_px",
                format!(
                    "{} px leaves no room for marks of {largest_mark} px",
                    self.long_side_px
                ),
            );
        }
        Ok(())
    }

    /// The Gaussians drawn under a camera at world height `camera_height_m`.
    fn selection(&self, camera_height_m: f64) -> Selection {
        Selection {
            max_height_m: camera_height_m,
            max_scale_m: self.max_gaussian_size_m,
            exclude_flags: FLAG_UNKNOWN_SPACE,
        }
    }
}

/// What is drawn over the map, in world metres.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Annotations {
    /// The robot's estimated planar pose `[x, y, yaw]` (yaw in radians about +z, 0 = +x).
    pub robot: [f64; 3],
    /// The visited path, `[x, y]` in visiting order.
    pub path: Vec<[f64; 2]>,
    /// The last chosen frontier, if any.
    pub last_frontier: Option<[f64; 2]>,
    /// Where candidate `i`'s number `i` is centred (the frontier cell nearest its centroid).
    pub candidates: Vec<[f64; 2]>,
}

impl Annotations {
    /// Names the first non-finite input.
    fn check(&self) -> Result<(), BevError> {
        let non_finite = |what: String, value: &[f64]| {
            if value.iter().all(|v| v.is_finite()) {
                Ok(())
            } else {
                Err(BevError::NonFinite {
                    what,
                    value: value.to_vec(),
                })
            }
        };
        non_finite("robot pose".into(), &self.robot)?;
        for (i, p) in self.path.iter().enumerate() {
            non_finite(format!("path point {i}"), p)?;
        }
        if let Some(p) = &self.last_frontier {
            non_finite("last frontier".into(), p)?;
        }
        for (i, p) in self.candidates.iter().enumerate() {
            non_finite(format!("candidate {i}"), p)?;
        }
        Ok(())
    }

    /// Every annotated point: robot, path, last frontier, candidates.
    fn points(&self) -> impl Iterator<Item = [f64; 2]> + '_ {
        std::iter::once([self.robot[0], self.robot[1]])
            .chain(self.path.iter().copied())
            .chain(self.last_frontier)
            .chain(self.candidates.iter().copied())
    }
}

/// Where a candidate's number was drawn.
#[derive(Debug, Clone, PartialEq)]
pub struct Label {
    /// The candidate index (the number shown).
    pub index: usize,
    /// The text drawn (`index` in decimal).
    pub text: String,
    /// Pixel coordinates of the candidate's point, where the ink box is centred.
    pub centre: [f64; 2],
    /// The glyph outlines' box `[x0, y0, x1, y1]`, pixel coordinates (without the halo).
    pub ink: [f64; 4],
}

/// An annotated bird's-eye view.
#[derive(Debug, Clone, PartialEq)]
pub struct Bev {
    /// `width × height × 3` bytes of RGB, row-major, row 0 at the top.
    pub rgb: Vec<u8>,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// The world rectangle shown (the world ↔ pixel mapping).
    pub window: OrthoWindow,
    /// The candidate numbers, in candidate order.
    pub labels: Vec<Label>,
}

impl Bev {
    /// Pixel coordinates `[column, row]` of a world point `[x, y]` (pixel centres at integers).
    pub fn pixel_of(&self, world: [f64; 2]) -> [f64; 2] {
        self.window.pixel_of(world)
    }

    /// The RGB bytes of pixel `(x, y)` (column, row).
    pub fn pixel(&self, x: usize, y: usize) -> [u8; 3] {
        let k = 3 * (y * self.width + x);
        [self.rgb[k], self.rgb[k + 1], self.rgb[k + 2]]
    }

    /// The image as an 8-bit RGB PNG (fast deflate; the same pixels give the same bytes).
    /// Panics if `rgb` does not hold `width × height × 3` bytes (never for a [`Bev`] made by
    /// [`annotate`]).
    pub fn png(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.rgb.len() / 4);
        let mut encoder = png::Encoder::new(&mut out, self.width as u32, self.height as u32);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_compression(png::Compression::Fast);
        // Writing a well-formed image into memory cannot fail.
        let mut writer = encoder
            .write_header()
            .expect("PNG header of a valid image into memory");
        writer
            .write_image_data(&self.rgb)
            .expect("PNG data of a valid image into memory");
        writer.finish().expect("PNG end into memory");
        out
    }
}

/// Why a BEV could not be made.
#[derive(Debug, thiserror::Error)]
pub enum BevError {
    /// An input coordinate is NaN or infinite.
    #[error("non-finite {what}: {value:?}")]
    NonFinite {
        /// Which input (e.g. "candidate 3", "camera height").
        what: String,
        /// Its value.
        value: Vec<f64>,
    },
    /// A setting is out of range.
    #[error("bev.{field}: {message}")]
    Config {
        /// The field of [`BevConfig`].
        field: &'static str,
        /// What is wrong with it.
        message: String,
    },
    /// The map could not be rendered (mismatched arrays, unusable window).
    #[error("map render: {0}")]
    Map(#[from] SplatError),
    /// The bundled font could not be read.
    #[error("bundled font: {0}")]
    Font(String),
}

/// Renders and annotates the BEV of `gaussians` seen from a camera at world height
/// `camera_height_m` (the ceiling cut): [`bev_window`] → [`render_map`] → [`annotate`]. An
/// empty map (or one with nothing below the camera) still gives an image, cropped to the marks.
pub fn render_bev(
    gaussians: &Gaussians<f32>,
    camera_height_m: f64,
    annotations: &Annotations,
    config: &BevConfig,
) -> Result<Bev, BevError> {
    let window = bev_window(gaussians, camera_height_m, annotations, config)?;
    let map = render_map(gaussians, camera_height_m, &window, config)?;
    annotate(map, annotations, config)
}

/// Stage 1: the world window. It holds the means of the drawn Gaussians (ignoring the 0.1 %
/// most extreme on each side of each axis, [`DEFAULT_TRIM_FRACTION`], so that a few stray
/// Gaussians far away do not shrink the map in the image) and every annotated point, with [`BevConfig::margin_m`]
/// around them plus room for the largest mark (a number with its halo, the star with its
/// heading tick) in pixels; its long side is [`BevConfig::long_side_px`].
pub fn bev_window(
    gaussians: &Gaussians<f32>,
    camera_height_m: f64,
    annotations: &Annotations,
    config: &BevConfig,
) -> Result<OrthoWindow, BevError> {
    config.check()?;
    check_height(camera_height_m)?;
    annotations.check()?;
    let selection = config.selection(camera_height_m);
    let map = mean_bounds(gaussians, &selection, DEFAULT_TRIM_FRACTION)?;
    let (mut lo, mut hi) = map.map_or(([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]), |b| {
        (b.min, b.max)
    });
    for p in annotations.points() {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let font = font()?;
    let pad_px = mark_reach_px(&font, annotations.candidates.len(), config) + 2.0;
    let long_px = config.long_side_px as f64;
    // The margin also keeps a single point (zero extent) a valid box.
    let margin = config.margin_m.max(1e-3);
    let long_m = (hi[0] - lo[0]).max(hi[1] - lo[1]) + 2.0 * margin;
    let metres_per_pixel = long_m / (long_px - 2.0 * pad_px);
    let grow = margin + pad_px * metres_per_pixel;
    let window = OrthoWindow::covering(
        [lo[0] - grow, lo[1] - grow],
        [hi[0] + grow, hi[1] + grow],
        config.long_side_px as usize,
    )?;
    Ok(window)
}

/// Stage 2: the orthographic render of the Gaussians below `camera_height_m` and no larger
/// than [`BevConfig::max_gaussian_size_m`] into `window`, on white.
pub fn render_map(
    gaussians: &Gaussians<f32>,
    camera_height_m: f64,
    window: &OrthoWindow,
    config: &BevConfig,
) -> Result<OrthoImage, BevError> {
    config.check()?;
    check_height(camera_height_m)?;
    let options = OrthoOptions {
        window: *window,
        selection: config.selection(camera_height_m),
    };
    Ok(render_ortho(gaussians, &options)?)
}

/// Stage 3: draws the marks over a map render (path, diamond, star, then the numbers on top).
pub fn annotate(
    map: OrthoImage,
    annotations: &Annotations,
    config: &BevConfig,
) -> Result<Bev, BevError> {
    config.check()?;
    annotations.check()?;
    let OrthoImage {
        rgb,
        width,
        height,
        window,
    } = map;
    let mut canvas = Pixmap::new(width as u32, height as u32).ok_or_else(|| {
        BevError::Map(SplatError::Ortho(format!(
            "canvas of {width}x{height} pixels"
        )))
    })?;
    for (dst, src) in canvas
        .data_mut()
        .chunks_exact_mut(4)
        .zip(rgb.chunks_exact(3))
    {
        dst[..3].copy_from_slice(src);
        dst[3] = 255;
    }
    // tiny-skia puts pixel centres at half-integers.
    let at = |world: [f64; 2]| {
        let p = window.pixel_of(world);
        ((p[0] + 0.5) as f32, (p[1] + 0.5) as f32)
    };
    let round = |width: f32| Stroke {
        width,
        line_cap: LineCap::Round,
        line_join: LineJoin::Round,
        ..Stroke::default()
    };
    let id = Transform::identity();

    if annotations.path.len() >= 2 {
        let mut pb = PathBuilder::new();
        for (i, &p) in annotations.path.iter().enumerate() {
            let (x, y) = at(p);
            if i == 0 {
                pb.move_to(x, y);
            } else {
                pb.line_to(x, y);
            }
        }
        if let Some(path) = pb.finish() {
            let stroke = round(config.path_width_px);
            canvas.stroke_path(&path, &paint(PATH_RGB), &stroke, id, None);
        }
    }

    if let Some(f) = annotations.last_frontier {
        let (x, y) = at(f);
        let r = config.diamond_radius_px;
        let corners = [(0.0, -r), (r, 0.0), (0.0, r), (-r, 0.0)].map(|(dx, dy)| (x + dx, y + dy));
        if let Some(path) = polygon(&corners) {
            let outline = Stroke {
                width: (r / 6.0).max(1.5),
                line_join: LineJoin::Round,
                ..Stroke::default()
            };
            canvas.fill_path(&path, &paint(FRONTIER_RGB), FillRule::Winding, id, None);
            canvas.stroke_path(&path, &paint(FRONTIER_OUTLINE_RGB), &outline, id, None);
        }
    }

    {
        let (x, y) = at([annotations.robot[0], annotations.robot[1]]);
        let r = config.star_radius_px;
        // Image rows run along −y: the heading angle flips.
        let heading = -annotations.robot[2] as f32;
        let (c, s) = (heading.cos(), heading.sin());
        let star: Vec<(f32, f32)> = (0..10)
            .map(|k| {
                let a = heading + k as f32 * std::f32::consts::PI / 5.0;
                let radius = if k % 2 == 0 { r } else { STAR_INNER * r };
                (x + radius * a.cos(), y + radius * a.sin())
            })
            .collect();
        if let Some(path) = polygon(&star) {
            let outline = Stroke {
                width: 1.5,
                line_join: LineJoin::Round,
                ..Stroke::default()
            };
            canvas.fill_path(&path, &paint(ROBOT_RGB), FillRule::Winding, id, None);
            canvas.stroke_path(&path, &paint(HALO_RGB), &outline, id, None);
        }
        // The heading tick continues the leading tip, over its outline.
        let mut tick = PathBuilder::new();
        tick.move_to(x + TICK_FROM * r * c, y + TICK_FROM * r * s);
        tick.line_to(x + TICK_REACH * r * c, y + TICK_REACH * r * s);
        if let Some(path) = tick.finish() {
            let stroke = round(config.path_width_px.max(2.0));
            canvas.stroke_path(&path, &paint(ROBOT_RGB), &stroke, id, None);
        }
    }

    let font = font()?;
    let mut labels = Vec::with_capacity(annotations.candidates.len());
    let halo = round(2.0 * config.label_halo_px);
    for (index, &p) in annotations.candidates.iter().enumerate() {
        let text = index.to_string();
        let centre = window.pixel_of(p);
        let (x, y) = at(p);
        let Some(path) = text_path(&font, &text, config.label_px)
            .and_then(|t| t.transform(Transform::from_translate(x, y)))
        else {
            continue;
        };
        if config.label_halo_px > 0.0 {
            canvas.stroke_path(&path, &paint(HALO_RGB), &halo, id, None);
        }
        canvas.fill_path(&path, &paint(LABEL_RGB), FillRule::Winding, id, None);
        let b = path.compute_tight_bounds().unwrap_or(path.bounds());
        let ink = [b.left(), b.top(), b.right(), b.bottom()].map(|v| v as f64 - 0.5);
        labels.push(Label {
            index,
            text,
            centre,
            ink,
        });
    }

    let mut out = rgb;
    for (dst, src) in out.chunks_exact_mut(3).zip(canvas.data().chunks_exact(4)) {
        // Every pixel is opaque, so the premultiplied bytes are the colour.
        dst.copy_from_slice(&src[..3]);
    }
    Ok(Bev {
        rgb: out,
        width,
        height,
        window,
        labels,
    })
}

/// The heading tick runs from this many star radii from the robot (inside the leading tip)...
const TICK_FROM: f32 = 0.8;
/// ...to this many.
const TICK_REACH: f32 = 1.7;
/// Inner radius of the star, in outer radii.
const STAR_INNER: f32 = 0.42;

fn check_height(camera_height_m: f64) -> Result<(), BevError> {
    if camera_height_m.is_finite() {
        Ok(())
    } else {
        Err(BevError::NonFinite {
            what: "camera height".into(),
            value: vec![camera_height_m],
        })
    }
}

fn font() -> Result<FontRef<'static>, BevError> {
    FontRef::try_from_slice(FONT_TTF).map_err(|e| BevError::Font(e.to_string()))
}

/// An opaque anti-aliased solid paint.
fn paint(rgb: [u8; 3]) -> Paint<'static> {
    let mut p = Paint::default();
    p.set_color_rgba8(rgb[0], rgb[1], rgb[2], 255);
    p.anti_alias = true;
    p
}

/// The closed polygon through `points`.
fn polygon(points: &[(f32, f32)]) -> Option<Path> {
    let (&(x0, y0), rest) = points.split_first()?;
    let mut pb = PathBuilder::new();
    pb.move_to(x0, y0);
    for &(x, y) in rest {
        pb.line_to(x, y);
    }
    pb.close();
    pb.finish()
}

/// How far from its anchor point any mark reaches, pixels: the star with its heading tick, the
/// diamond, and the widest of the numbers `0..n` with its halo.
fn mark_reach_px(font: &FontRef<'_>, n: usize, config: &BevConfig) -> f64 {
    let mut reach = (TICK_REACH * config.star_radius_px + config.path_width_px)
        .max(config.diamond_radius_px + 2.0);
    // The widest number has the most digits; all digits of the font share one advance.
    if let Some(path) = n
        .checked_sub(1)
        .and_then(|last| text_path(font, &last.to_string(), config.label_px))
    {
        let b = path.compute_tight_bounds().unwrap_or(path.bounds());
        reach = reach.max(b.right().max(b.bottom()) + config.label_halo_px);
    }
    reach as f64
}

/// The outline of `text` in the bundled font at an em size of `em_px` pixels, its ink box
/// centred at the origin (y down). `None` for text without ink.
fn text_path(font: &FontRef<'_>, text: &str, em_px: f32) -> Option<Path> {
    let scale = em_px / font.units_per_em()?;
    let mut pb = PathBuilder::new();
    let mut pen = 0.0f32;
    let mut previous: Option<GlyphId> = None;
    for ch in text.chars() {
        let glyph = font.glyph_id(ch);
        if let Some(p) = previous {
            pen += font.kern_unscaled(p, glyph) * scale;
        }
        if let Some(outline) = font.outline(glyph) {
            // Font units are y-up; a new contour starts where a curve does not continue the
            // previous one.
            let map = |p: ab_glyph::Point| (pen + p.x * scale, -p.y * scale);
            let mut last: Option<ab_glyph::Point> = None;
            for curve in &outline.curves {
                let (start, end) = match curve {
                    OutlineCurve::Line(a, b) => (*a, *b),
                    OutlineCurve::Quad(a, _, b) => (*a, *b),
                    OutlineCurve::Cubic(a, _, _, b) => (*a, *b),
                };
                if last != Some(start) {
                    if last.is_some() {
                        pb.close();
                    }
                    let (x, y) = map(start);
                    pb.move_to(x, y);
                }
                match curve {
                    OutlineCurve::Line(_, b) => {
                        let (x, y) = map(*b);
                        pb.line_to(x, y);
                    }
                    OutlineCurve::Quad(_, c, b) => {
                        let ((cx, cy), (x, y)) = (map(*c), map(*b));
                        pb.quad_to(cx, cy, x, y);
                    }
                    OutlineCurve::Cubic(_, c1, c2, b) => {
                        let ((ax, ay), (bx, by), (x, y)) = (map(*c1), map(*c2), map(*b));
                        pb.cubic_to(ax, ay, bx, by, x, y);
                    }
                }
                last = Some(end);
            }
            if last.is_some() {
                pb.close();
            }
        }
        pen += font.h_advance_unscaled(glyph) * scale;
        previous = Some(glyph);
    }
    let path = pb.finish()?;
    let b = path.compute_tight_bounds()?;
    let (cx, cy) = (0.5 * (b.left() + b.right()), 0.5 * (b.top() + b.bottom()));
    path.transform(Transform::from_translate(-cx, -cy))
}

#[cfg(test)]
mod tests;
