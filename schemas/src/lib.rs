//! Every message type of the dataflow (SPEC §1) and its topic, with schema versions.
//!
//! Two wire formats:
//! - **small messages** (actions, poses, paths, ...) are serde structs encoded with postcard behind a
//!   2-byte schema-version prefix ([`SmallMessage`]);
//! - **large payloads** (RGB-D frames, Gaussian maps, occupancy grids) are a `#[repr(C)]` header
//!   followed by 8-byte aligned slices ([`rgbd`], [`gaussian_map`], [`occupancy`]), so a producer can
//!   write them in place into a loaned shared-memory sample and a consumer can read them without a copy.
//!
//! Every payload carries its schema version; decoding a payload with another version, a truncated
//! payload or garbage is an [`SchemaError`], never a panic. [`MessageKind`] names every type, its
//! transport class and whether it is evaluation-only (ground truth). Topics are `node/output` of
//! the dataflow file that declares them; the runtime resolves each input's message kind from its
//! producer's port, so no list of canonical topic names is kept here.

pub mod error;
#[doc(hidden)]
pub mod fuzzing;
pub mod gaussian_map;
pub mod kind;
mod layout;
pub mod messages;
pub mod occupancy;
pub mod rgbd;
pub mod small;

pub use error::SchemaError;
pub use gaussian_map::{
    GaussianMap, GaussianMapHeader, GaussianMapMut, GaussianMapView, SECTION_WIDTHS,
};
pub use kind::{MessageKind, Payload, TransportClass};
pub use messages::*;
pub use occupancy::{CellState, OccupancyGrid, OccupancyGridHeader, OccupancyGridView};
pub use rgbd::{RgbdFrame, RgbdFrameHeader, RgbdFrameMut, RgbdFrameView};
pub use small::SmallMessage;
