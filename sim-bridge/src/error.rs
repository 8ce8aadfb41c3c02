//! The error type of the simulator library: every variant names what failed and where.

use std::path::PathBuf;

/// Why loading a scene, configuring the simulator or generating a house failed.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The scene file does not exist or cannot be read.
    #[error("cannot read scene file {path}: {source}")]
    Io {
        /// The file that could not be read.
        path: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// The file extension names no format the simulator reads.
    #[error("unsupported scene format for {path}: expected .glb, .gltf, .obj or .ply")]
    UnsupportedFormat {
        /// The file with the unknown extension.
        path: PathBuf,
    },
    /// The file exists but its content is not a valid scene of its format.
    #[error("malformed {format} scene {path}: {reason}")]
    Malformed {
        /// Format name ("glTF", "OBJ", "PLY").
        format: &'static str,
        /// The offending file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A texture referenced by a scene could not be loaded.
    #[error("cannot load texture {texture} of scene {scene}: {reason}")]
    Texture {
        /// The scene that references the texture.
        scene: PathBuf,
        /// The texture (file name or glTF image index).
        texture: String,
        /// What went wrong.
        reason: String,
    },
    /// The scene holds no triangles at all.
    #[error("scene {0} contains no triangles")]
    EmptyScene(String),
    /// A configuration value is outside its valid range.
    #[error("invalid configuration: {field} = {value} ({reason})")]
    InvalidConfig {
        /// The configuration field.
        field: &'static str,
        /// Its value, formatted.
        value: String,
        /// The constraint it breaks.
        reason: &'static str,
    },
    /// A scene file cannot be placed in the world: a transform that is not a rotation times a
    /// uniform scale, or `floor: auto` finding no floor.
    #[error("cannot place scene {scene}: {reason}")]
    Placement {
        /// The scene (file path).
        scene: String,
        /// What went wrong, and what to try.
        reason: String,
    },
    /// No navigable position exists in the scene for the agent.
    #[error("scene {0} has no navigable floor for the agent (check floor height and agent radius)")]
    NoNavigableArea(String),
    /// A requested start pose is not navigable.
    #[error("start pose ({x:.3}, {y:.3}) is not navigable")]
    StartNotNavigable {
        /// World x of the start.
        x: f64,
        /// World y of the start.
        y: f64,
    },
    /// An output buffer handed to the renderer has the wrong length for the image size.
    #[error(
        "render target {what} holds {len} elements, the {width}x{height} image needs {expected}"
    )]
    RenderTarget {
        /// Which buffer ("rgb" or "depth").
        what: &'static str,
        /// Its length.
        len: usize,
        /// The length the image needs.
        expected: usize,
        /// Image width, pixels.
        width: u32,
        /// Image height, pixels.
        height: u32,
    },
    /// Writing a scene file failed.
    #[error("cannot write {path}: {reason}")]
    Write {
        /// The file being written.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
}

/// Shorthand for results of this crate.
pub type Result<T> = std::result::Result<T, SimError>;
