//! Scene files: glTF 2.0 (`.gltf`, `.glb`), Wavefront OBJ + MTL (`.obj`) and PLY (`.ply`).
//!
//! Every loader returns a [`Scene`] in the world frame (z up). glTF is y-up by its
//! specification, so glTF positions are rotated by +90° about x: `(x, y, z)_gltf →
//! (x, −z, y)_world`. OBJ files carry no up axis; most exporters (and Habitat's assets) write
//! y-up, which is the default, while PLY scans (Replica, ScanNet, Matterport) are z-up by
//! default. [`LoadOptions::up_axis`] overrides both.
//!
//! Unreadable or malformed files are errors naming the file. A texture that is missing or
//! cannot be decoded is not: the material falls back to its flat colour and the loader
//! reports a [`LoadWarning`], since a user would rather see the scene than nothing.

mod gltf_scene;
mod obj_scene;
mod ply_scene;

use crate::error::{Result, SimError};
use crate::scene::Scene;
use std::path::{Path, PathBuf};

/// Which axis of a file points up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UpAxis {
    /// +y is up (glTF, most OBJ exporters): rotated to z-up on load.
    Y,
    /// +z is up (the world convention): kept as is.
    Z,
}

impl UpAxis {
    /// Parses `"y"` / `"z"` (case-insensitive), e.g. from a node's configuration.
    pub fn from_name(name: &str) -> Option<UpAxis> {
        match name.trim().to_ascii_lowercase().as_str() {
            "y" | "+y" | "y-up" => Some(UpAxis::Y),
            "z" | "+z" | "z-up" => Some(UpAxis::Z),
            _ => None,
        }
    }

    /// The name [`UpAxis::from_name`] reads back: `"y"` or `"z"`.
    pub fn name(self) -> &'static str {
        match self {
            UpAxis::Y => "y",
            UpAxis::Z => "z",
        }
    }

    /// Maps a point of a file with this up axis to the z-up world frame.
    pub fn to_world(self, p: [f32; 3]) -> [f32; 3] {
        match self {
            UpAxis::Y => [p[0], -p[2], p[1]],
            UpAxis::Z => p,
        }
    }

    /// Maps a z-up world point to a file with this up axis (inverse of [`UpAxis::to_world`]).
    pub fn from_world(self, p: [f32; 3]) -> [f32; 3] {
        match self {
            UpAxis::Y => [p[0], p[2], -p[1]],
            UpAxis::Z => p,
        }
    }
}

/// Options for [`load_scene`].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LoadOptions {
    /// Up axis of the file; `None` = the format's default (glTF and OBJ: y, PLY: z).
    pub up_axis: Option<UpAxis>,
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
}

/// Loads a scene file, choosing the format by extension (case-insensitive).
pub fn load_scene(path: &Path, options: &LoadOptions) -> Result<Loaded> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    if !matches!(ext.as_str(), "glb" | "gltf" | "obj" | "ply") {
        return Err(SimError::UnsupportedFormat {
            path: path.to_path_buf(),
        });
    }
    let bytes = std::fs::read(path).map_err(|source| SimError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut warnings = Vec::new();
    let scene = match ext.as_str() {
        "glb" | "gltf" => gltf_scene::load(path, &bytes, options, &mut warnings)?,
        "obj" => obj_scene::load(path, options, &mut warnings)?,
        _ => ply_scene::load(path, &bytes, options)?,
    };
    scene.validate()?;
    Ok(Loaded { scene, warnings })
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
