//! Scene files: glTF 2.0 (`.gltf`, `.glb`), Wavefront OBJ + MTL (`.obj`) and PLY (`.ply`).
//!
//! Every loader returns a [`Scene`] in the world frame (z up). glTF is y-up by its
//! specification, so glTF positions are rotated by +90° about x: `(x, y, z)_gltf →
//! (x, −z, y)_world`. OBJ files carry no up axis; most exporters (and Habitat's assets) write
//! y-up, which is the default, while PLY scans (Replica, ScanNet, Matterport) are z-up by
//! default. [`LoadOptions::placement`] overrides both with any of ±x, ±y, ±z ([`UpAxis`]), and
//! then places the scene: a rotation, translation and uniform scale ([`Transform`]) and, with
//! [`Floor::Auto`], levelling on the floor plane found in the mesh (see [`placement`]).
//!
//! Unreadable or malformed files are errors naming the file. A texture that is missing or
//! cannot be decoded is not: the material falls back to its flat colour and the loader
//! reports a [`LoadWarning`], since a user would rather see the scene than nothing.

mod gltf_scene;
mod obj_scene;
pub mod placement;
mod ply_scene;

pub use placement::{
    Floor, FloorCandidate, Levelling, Placement, PlacementReport, Transform, UpDecision,
};

use crate::error::{Result, SimError};
use crate::scene::Scene;
use std::path::{Path, PathBuf};

/// Which axis of a file points up: one of ±x, ±y, ±z.
///
/// Each maps the file's frame to the z-up world by a proper rotation (determinant +1, so
/// triangle winding and hence [`Scene::scaled_normal`] directions are kept), chosen as the
/// quarter or half turn about a file axis that takes the up axis to world +z:
///
/// | up axis | rotation     | file `(x, y, z)` → world |
/// |---------|--------------|--------------------------|
/// | `x`     | −90° about y | `(−z, y, x)`             |
/// | `-x`    | +90° about y | `(z, y, −x)`             |
/// | `y`     | +90° about x | `(x, −z, y)`             |
/// | `-y`    | −90° about x | `(x, z, −y)`             |
/// | `z`     | none         | `(x, y, z)`              |
/// | `-z`    | 180° about x | `(x, −y, −z)`            |
/// | `auto`  | none (found) | `(x, y, z)`, then levelled |
///
/// `auto` is not an axis but a request: the file is read as it is and the placement finds
/// which way is up from the mesh's own planes, at any tilt (see [`placement::auto_up`]).
///
/// `-y` reads a mesh in an OpenCV camera frame (x right, y down, z forward, e.g. an RGB-D
/// reconstruction in its first camera's frame) as x right, y forward, z up.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum UpAxis {
    /// +x is up.
    X,
    /// −x is up.
    NegX,
    /// +y is up (glTF, most OBJ exporters).
    Y,
    /// −y is up (camera-frame scans: y points down).
    NegY,
    /// +z is up (the world convention; PLY scans): kept as is.
    Z,
    /// −z is up.
    NegZ,
    /// Unknown: found from the mesh (its floor and walls) by the placement.
    Auto,
}

impl UpAxis {
    /// The six axes (every up axis but [`UpAxis::Auto`]), in the order x, −x, y, −y, z, −z.
    pub const ALL: [UpAxis; 6] = [
        UpAxis::X,
        UpAxis::NegX,
        UpAxis::Y,
        UpAxis::NegY,
        UpAxis::Z,
        UpAxis::NegZ,
    ];

    /// Parses an axis name, case-insensitive, e.g. from a node's configuration: `x`, `+x`, `-x`
    /// (likewise y, z), optionally with an `-up` suffix (`y-up`, `-z-up`), or `auto`.
    pub fn from_name(name: &str) -> Option<UpAxis> {
        let name = name.trim().to_ascii_lowercase();
        if name == "auto" {
            return Some(UpAxis::Auto);
        }
        let name = name.strip_suffix("-up").unwrap_or(&name);
        let (negative, axis) = match name.strip_prefix('-') {
            Some(rest) => (true, rest),
            None => (false, name.strip_prefix('+').unwrap_or(name)),
        };
        Some(match (axis, negative) {
            ("x", false) => UpAxis::X,
            ("x", true) => UpAxis::NegX,
            ("y", false) => UpAxis::Y,
            ("y", true) => UpAxis::NegY,
            ("z", false) => UpAxis::Z,
            ("z", true) => UpAxis::NegZ,
            _ => return None,
        })
    }

    /// The name [`UpAxis::from_name`] reads back: `x`, `-x`, `y`, `-y`, `z`, `-z` or `auto`.
    pub fn name(self) -> &'static str {
        match self {
            UpAxis::X => "x",
            UpAxis::NegX => "-x",
            UpAxis::Y => "y",
            UpAxis::NegY => "-y",
            UpAxis::Z => "z",
            UpAxis::NegZ => "-z",
            UpAxis::Auto => "auto",
        }
    }

    /// The accepted names, for error messages.
    pub const NAMES: &'static str =
        "x, -x, y, -y, z or -z, or auto (case-insensitive, `+` and `-up` allowed)";

    /// Maps a point of a file with this up axis to the z-up world frame (see the type's table;
    /// exact: coordinates are only permuted and negated). [`UpAxis::Auto`] keeps the point as
    /// it is (the placement turns the scene once it has found the floor).
    pub fn to_world(self, p: [f32; 3]) -> [f32; 3] {
        match self {
            UpAxis::X => [-p[2], p[1], p[0]],
            UpAxis::NegX => [p[2], p[1], -p[0]],
            UpAxis::Y => [p[0], -p[2], p[1]],
            UpAxis::NegY => [p[0], p[2], -p[1]],
            UpAxis::Z | UpAxis::Auto => p,
            UpAxis::NegZ => [p[0], -p[1], -p[2]],
        }
    }

    /// Maps a z-up world point to a file with this up axis (inverse of [`UpAxis::to_world`]).
    pub fn from_world(self, p: [f32; 3]) -> [f32; 3] {
        match self {
            UpAxis::X => [p[2], p[1], -p[0]],
            UpAxis::NegX => [-p[2], p[1], p[0]],
            UpAxis::Y => [p[0], p[2], -p[1]],
            UpAxis::NegY => [p[0], -p[2], p[1]],
            UpAxis::Z | UpAxis::Auto => p,
            UpAxis::NegZ => [p[0], -p[1], -p[2]],
        }
    }

    /// The rotation of [`UpAxis::to_world`] as a matrix (file → world).
    pub fn rotation(self) -> nalgebra::Rotation3<f64> {
        let column = |p: [f32; 3]| {
            let w = self.to_world(p);
            nalgebra::Vector3::new(w[0] as f64, w[1] as f64, w[2] as f64)
        };
        nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[
            column([1.0, 0.0, 0.0]),
            column([0.0, 1.0, 0.0]),
            column([0.0, 0.0, 1.0]),
        ]))
    }
}

impl std::fmt::Display for UpAxis {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Written as its [`UpAxis::name`], so configs and `summary.json` hold `up_axis: -y`.
impl serde::Serialize for UpAxis {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

/// Read with [`UpAxis::from_name`]; anything else is an error naming the accepted values.
impl<'de> serde::Deserialize<'de> for UpAxis {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        UpAxis::from_name(&name).ok_or_else(|| {
            serde::de::Error::custom(format!("up_axis must be {}, got \"{name}\"", UpAxis::NAMES))
        })
    }
}

/// Options for [`load_scene`].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LoadOptions {
    /// Where the scene goes in the world: up axis (`None` = the format's default: glTF and OBJ
    /// y, PLY z), then transform and floor levelling ([`Placement`]).
    pub placement: Placement,
}

impl LoadOptions {
    /// Options that only set the file's up axis.
    pub fn up_axis(up: UpAxis) -> Self {
        Self {
            placement: Placement {
                up_axis: Some(up),
                ..Placement::default()
            },
        }
    }
}

/// Something the loader worked around (a missing texture, an unsupported primitive).
#[derive(Debug, Clone, PartialEq)]
pub struct LoadWarning {
    /// The scene file.
    pub file: PathBuf,
    /// What was skipped or replaced.
    pub message: String,
}

impl std::fmt::Display for LoadWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "warning: {}: {}", self.file.display(), self.message)
    }
}

/// A loaded scene and the warnings met on the way.
#[derive(Debug, Clone)]
pub struct Loaded {
    /// The scene, in the world frame.
    pub scene: Scene,
    /// Non-fatal problems (the scene is still usable).
    pub warnings: Vec<LoadWarning>,
    /// What the placement did (up axis, transform, tilt removed, floor height), for the caller
    /// to print; `None` when no placement key was set (the format's default up axis only).
    pub placement: Option<PlacementReport>,
}

/// The scene file formats [`load_scene`] reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SceneFormat {
    /// glTF 2.0, JSON (`.gltf`) or binary (`.glb`).
    Gltf,
    /// Wavefront OBJ (`.obj`), with an optional MTL material library.
    Obj,
    /// PLY mesh (`.ply`).
    Ply,
}

impl SceneFormat {
    /// The format of a file by its extension (case-insensitive); `None` if unsupported.
    pub fn from_path(path: &Path) -> Option<SceneFormat> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        Some(match ext.as_str() {
            "glb" | "gltf" => SceneFormat::Gltf,
            "obj" => SceneFormat::Obj,
            "ply" => SceneFormat::Ply,
            _ => return None,
        })
    }

    /// The up axis of files of this format when none is configured.
    fn default_up(self) -> UpAxis {
        match self {
            SceneFormat::Gltf | SceneFormat::Obj => UpAxis::Y,
            SceneFormat::Ply => UpAxis::Z,
        }
    }
}

/// Loads a scene file, choosing the format by extension (case-insensitive).
pub fn load_scene(path: &Path, options: &LoadOptions) -> Result<Loaded> {
    let format = SceneFormat::from_path(path).ok_or_else(|| SimError::UnsupportedFormat {
        path: path.to_path_buf(),
    })?;
    let bytes = std::fs::read(path).map_err(|source| SimError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let base = path.parent().unwrap_or_else(|| Path::new("."));
    load_scene_bytes(&bytes, format, path, Some(base), options)
}

/// Loads a scene from the bytes of a file of format `format`; `path` only names it in errors
/// and warnings. External files (an OBJ's material library and textures, a glTF's buffers and
/// images) are read relative to the folder `base`; with `base` `None` nothing outside `bytes`
/// is read: a glTF external buffer is then an error, a material library or texture a warning.
pub fn load_scene_bytes(
    bytes: &[u8],
    format: SceneFormat,
    path: &Path,
    base: Option<&Path>,
    options: &LoadOptions,
) -> Result<Loaded> {
    let mut warnings = Vec::new();
    let mut scene = match format {
        SceneFormat::Gltf => gltf_scene::load(path, bytes, base, options, &mut warnings)?,
        SceneFormat::Obj => obj_scene::load(path, bytes, base, options, &mut warnings)?,
        SceneFormat::Ply => ply_scene::load(path, bytes, options)?,
    };
    scene.validate()?;
    // The loader applied the up axis to every vertex; the rest of the placement follows.
    let placement = &options.placement;
    let up = placement.up_axis.unwrap_or(format.default_up());
    let (report, placement_warnings) =
        placement.finish(&mut scene, up, &nalgebra::Similarity3::identity())?;
    warnings.extend(placement_warnings);
    scene.validate()?;
    Ok(Loaded {
        scene,
        warnings,
        placement: (*placement != Placement::default()).then_some(report),
    })
}

impl Scene {
    /// Loads a scene file with default options, printing any warnings to stderr.
    pub fn load(path: &Path) -> Result<Scene> {
        let loaded = load_scene(path, &LoadOptions::default())?;
        for w in &loaded.warnings {
            eprintln!("{w}");
        }
        Ok(loaded.scene)
    }
}

/// The message of a panic caught from a format crate, for the error that replaces it.
pub(crate) fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_else(|| "unknown".into())
}

/// Converts a decoded image to an RGB8 texture (alpha dropped, grey expanded, 16 bits reduced).
pub(crate) fn texture_from_image(
    name: String,
    image: image::DynamicImage,
    wrap_u: crate::scene::Wrap,
    wrap_v: crate::scene::Wrap,
) -> crate::scene::Texture {
    let rgb = image.to_rgb8();
    let (width, height) = rgb.dimensions();
    let texels = rgb.pixels().map(|p| p.0).collect();
    crate::scene::Texture {
        name,
        width,
        height,
        texels,
        wrap_u,
        wrap_v,
    }
}
