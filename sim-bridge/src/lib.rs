//! Built-in RGB-D simulator: mesh scenes, procedural houses, Habitat-style motion, ground truth.
//!
//! It stands in for Habitat (SPEC §1): a ground robot with an RGB-D camera moves by discrete
//! actions through a triangle-mesh scene.
//!
//! - Scenes: [`Scene::load`] / [`load::load_scene`] read glTF/GLB, OBJ+MTL and PLY (converted
//!   to the z-up world frame; glTF is y-up); [`house::generate`] builds seeded multi-room houses
//!   and [`export::write_glb`] saves any scene as GLB. [`SceneSpec`] names either (a
//!   `house:<seed>` or a file, with its size limits or its [`Placement`]: up axis, transform and
//!   floor levelling), so that every consumer builds the same scene.
//! - Rendering: [`render::Renderer`] rasterises RGB8 colour and z-depth (metres, f32, 0 = no
//!   reading) for any [`Intrinsics`] and pose `T_world_camera` (OpenCV optical frame);
//!   [`Simulator::render_into`] / [`Renderer::render_into`] write straight into caller buffers
//!   (the `sim` operator's loaned shared-memory frame) without allocating.
//! - Motion: [`Simulator::step`] applies [`Action::Forward`] (0.05 m), [`Action::TurnLeft`] /
//!   [`Action::TurnRight`] (5°); a cylinder agent (radius 0.1 m, camera 0.88 m above the floor)
//!   stops at or slides along obstacles ([`navigation`]).
//! - Noise, off by default ([`noise`]): structured-light depth noise σ = σ0 + c2·z² with range,
//!   edge and random dropouts, colour noise, and Habitat-style actuation noise, each from its
//!   own seeded stream; [`NoiseConfig`] reads `none`, `realistic` (RealSense D435 depth,
//!   LoCoBot-derived motion) or a preset with overrides.
//! - Ground truth, for evaluation only: [`Simulator::true_pose`], [`ground_truth`]
//!   (surface samples, test poses, navigable map).
//! - [`bench::run`]: frames per second (`activemap bench sim`).
//! - `BRIDGE.md`, `python/activemap_bridge.py` and `python/activemap_sim_client.py`: how an
//!   external simulator takes the `sim` node's place (topics, byte layouts, the launcher's
//!   environment), and a Python client that does so over Zenoh (box-room ray caster for CI, a
//!   habitat-sim adapter).
//!
//! ```no_run
//! use activemap_sim::{Action, SimConfig, Simulator, house};
//! let house = house::generate(7, &house::HouseConfig::default()).unwrap();
//! let mut sim = Simulator::new(house.scene, SimConfig::with_resolution(400, 400)).unwrap();
//! let result = sim.step(Action::Forward);
//! let frame = sim.render(); // frame.rgb (RGB8), frame.depth (metres)
//! let truth = sim.true_pose(); // evaluation only
//! # let _ = (result, frame, truth);
//! ```

pub mod bench;
pub mod error;
pub mod export;
#[doc(hidden)]
pub mod fuzzing;
pub mod ground_truth;
pub mod house;
pub mod inspect;
pub mod load;
pub mod navigation;
pub mod noise;
pub mod procedural_texture;
pub mod render;
pub mod scene;
pub mod scene_spec;
pub mod simulator;

pub use activemap_geometry::{Intrinsics, PlanarPose};
pub use error::{Result, SimError};
pub use load::{Floor, Placement, PlacementReport, Transform, UpAxis};
pub use navigation::{AgentShape, NavigableMap, Navigation, Room, Rooms};
pub use noise::{ActuationNoise, ColourNoise, DepthNoise, NoiseConfig, NoisePreset};
pub use render::{DepthRange, Renderer, RgbdFrame};
pub use scene::{Material, Scene, Texture, Triangle, Vertex, Wrap};
pub use scene_spec::SceneSpec;
pub use simulator::{Action, SimConfig, Simulator, StepResult};

#[cfg(test)]
mod tests;
