//! The Foxglove view of a run (issue 17): the pipeline's messages turned into Foxglove's
//! well-known schemas, so a recording opens in Foxglove (or any MCAP tool that knows them) and a
//! running episode can be watched live.
//!
//! Stages, each testable alone:
//! - [`ViewTopic`]: the fixed table of view channels (topic, Foxglove schema, encoding);
//! - [`ViewConverter`]: one pipeline message (its [`MessageKind`] and bytes) in, zero or more
//!   [`ViewMessage`]s out, with the decimation of [`ViewSettings`];
//! - [`images`]: colour to JPEG, depth to a colour-mapped PNG;
//! - [`LiveView`]: the same messages served over the Foxglove WebSocket protocol on loopback.
//!
//! The view channels sit beside the exact channels that replay needs; nothing reads them back
//! into the pipeline. Frames: `world` (SPEC §2, z up), `camera` (the tracker's estimate,
//! OpenCV optical axes as Foxglove's images expect) and `camera_true` (ground truth, from the
//! evaluation-only `TruePose`).

pub mod convert;
pub mod images;
pub mod live;
pub mod topics;

pub use convert::{ViewConverter, ViewError, ViewMessage, ViewSettings};
pub use live::LiveView;
pub use topics::ViewTopic;

pub use activemap_schemas::MessageKind;
/// The Foxglove SDK, for decoding view messages with the same schema types.
pub use foxglove;
