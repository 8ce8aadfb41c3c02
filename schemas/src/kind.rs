//! The catalogue of message types: name, transport class, evaluation-only flag, schema version,
//! and the [`Payload`] trait that encodes any of them to bytes.

use crate::messages::*;
use crate::small::SmallMessage;
use crate::{GaussianMap, GaussianMapHeader, OccupancyGrid, OccupancyGridHeader, RgbdFrame};
use crate::{RgbdFrameHeader, SchemaError};

/// How a message type travels between processes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TransportClass {
    /// Large payload: iceoryx2 shared memory on one machine (loan and write in place), bridged over
    /// Zenoh when a consumer is on another machine.
    SharedMemory,
    /// Small serde message: Zenoh.
    Small,
}

macro_rules! kinds {
    ($( $kind:ident : $class:ident, $eval:expr, $version:expr, $doc:literal; )*) => {
        /// Every message type of the dataflow.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
        pub enum MessageKind {
            $( #[doc = $doc] $kind, )*
        }

        impl MessageKind {
            /// All kinds, in declaration order.
            pub const ALL: &'static [MessageKind] = &[$(MessageKind::$kind),*];

            /// Type name as written in dataflow files and recordings.
            pub fn name(self) -> &'static str {
                match self { $(MessageKind::$kind => stringify!($kind),)* }
            }

            /// How the type travels.
            pub fn transport_class(self) -> TransportClass {
                match self { $(MessageKind::$kind => TransportClass::$class,)* }
            }

            /// True for ground truth, which only evaluation nodes may subscribe to.
            pub fn evaluation_only(self) -> bool {
                match self { $(MessageKind::$kind => $eval,)* }
            }

            /// Schema version this build writes and reads.
            pub fn schema_version(self) -> u32 {
                match self { $(MessageKind::$kind => $version,)* }
            }

            /// One-line description, embedded as the schema text in recordings.
            pub fn description(self) -> &'static str {
                match self { $(MessageKind::$kind => $doc,)* }
            }
        }
    };
}

kinds! {
    RgbdFrame: SharedMemory, false, RgbdFrameHeader::VERSION,
        "RGB-D frame: repr(C) RgbdFrameHeader, rgb8 [w*h*3], depth f32 metres [w*h], sections 8-byte aligned";
    GaussianMap: SharedMemory, false, GaussianMapHeader::VERSION,
        "Gaussian map: repr(C) GaussianMapHeader (frame_id, count, keyframe_id), f32 SoA means[3n] colors[3n] rotations[4n] opacities[n] log_scales[3n], u64 ids[n] (stable per Gaussian), sections 8-byte aligned";
    OccupancyGrid: SharedMemory, false, OccupancyGridHeader::VERSION,
        "Occupancy grid: repr(C) OccupancyGridHeader, u8 cells [w*h] row-major (0 free, 1 occupied, 2 unknown)";
    Action: Small, false, <Action as SmallMessage>::VERSION as u32,
        "Action { step: u64, action: Forward|TurnLeft|TurnRight|Stop } (u16 version + postcard)";
    PoseEstimate: Small, false, <PoseEstimate as SmallMessage>::VERSION as u32,
        "PoseEstimate { frame_id, stamp, t_world_camera, status: Ok|Lost|Skipped, residuals, iterations, graph_anchor: Option<frame_id>, keyframe_corrections: [(frame_id, T_after·T_before⁻¹)], lost_reason: Option<LowOverlap|DepthResidual|ColourResidual|MotionMismatch|NonFinite>, relocalised: Option<(metres, degrees, frames)> } (u16 version + postcard)";
    TruePose: Small, true, <TruePose as SmallMessage>::VERSION as u32,
        "TruePose { frame_id, stamp, t_world_camera } ground truth, evaluation only (u16 version + postcard)";
    Frontiers: Small, false, <Frontiers as SmallMessage>::VERSION as u32,
        "Frontiers { frame_id, stamp, regions: [{ id, size_cells, centroid, closest_reachable_cell, path_distance_m, anchor }] } (u16 version + postcard)";
    Goal: Small, false, <Goal as SmallMessage>::VERSION as u32,
        "Goal { frame_id, target: i32 (-1 = refine), focus: [x, y] } (u16 version + postcard)";
    Path: Small, false, <Path as SmallMessage>::VERSION as u32,
        "Path { frame_id, waypoints: [{ x, y, yaw }], objective } (u16 version + postcard)";
    ReplanRequest: Small, false, <ReplanRequest as SmallMessage>::VERSION as u32,
        "ReplanRequest { frame_id, reason } (u16 version + postcard)";
    EpisodeStatus: Small, false, <EpisodeStatus as SmallMessage>::VERSION as u32,
        "EpisodeStatus { step, max_steps, state: Running|Finished|Failed, message } (u16 version + postcard)";
    FisherReport: Small, false, <FisherReport as SmallMessage>::VERSION as u32,
        "FisherReport { frame_id, refine, focus, candidates: [{ x, y, yaw, eig }], paths: [{ goal, waypoints, actions, scored_steps, eig, c_local, objective }], chosen: i32 (-1 none), gaussians, unknown_gaussians, model_reused, note, timings, fallback } one Fisher replan (u16 version + postcard)";
    LlmExchange: Small, false, <LlmExchange as SmallMessage>::VERSION as u32,
        "LlmExchange { frame_id, system, prompt, bev_png, provider, model, request, candidates, http_status, attempts, latency_ms, prompt_tokens, completion_tokens, reply, target, reason, decision, fallback_target, failure, failure_detail, finish_reason, reasoning, schema_refused, follow_up, answered_frame, stale } (u16 version + postcard)";
    Counter: Small, false, <Counter as SmallMessage>::VERSION as u32,
        "Counter { seq: u64, value: i64 } diagnostics and runtime tests (u16 version + postcard)";
}

impl MessageKind {
    /// Look a kind up by its type name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.iter().copied().find(|k| k.name() == name)
    }
}

/// Anything that can be sent on a topic: a kind plus an encoding to and from bytes.
pub trait Payload: Sized {
    /// The message kind.
    const KIND: MessageKind;
    /// Encode to bytes.
    fn to_bytes(&self) -> Result<Vec<u8>, SchemaError>;
    /// Decode from bytes.
    fn from_bytes(bytes: &[u8]) -> Result<Self, SchemaError>;
}

macro_rules! small_payload {
    ($($ty:ident),*) => {$(
        impl Payload for $ty {
            const KIND: MessageKind = MessageKind::$ty;
            fn to_bytes(&self) -> Result<Vec<u8>, SchemaError> {
                Ok(SmallMessage::encode(self))
            }
            fn from_bytes(bytes: &[u8]) -> Result<Self, SchemaError> {
                <$ty as SmallMessage>::decode(bytes)
            }
        }
    )*};
}
small_payload!(
    Action,
    PoseEstimate,
    TruePose,
    Frontiers,
    Goal,
    Path,
    ReplanRequest,
    EpisodeStatus,
    FisherReport,
    LlmExchange,
    Counter
);

macro_rules! large_payload {
    ($($ty:ident),*) => {$(
        impl Payload for $ty {
            const KIND: MessageKind = MessageKind::$ty;
            fn to_bytes(&self) -> Result<Vec<u8>, SchemaError> {
                self.encode()
            }
            fn from_bytes(bytes: &[u8]) -> Result<Self, SchemaError> {
                $ty::decode(bytes)
            }
        }
    )*};
}
large_payload!(RgbdFrame, GaussianMap, OccupancyGrid);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_classes() {
        for &k in MessageKind::ALL {
            assert_eq!(MessageKind::from_name(k.name()), Some(k));
        }
        assert_eq!(MessageKind::from_name("Nope"), None);
        assert_eq!(
            MessageKind::RgbdFrame.transport_class(),
            TransportClass::SharedMemory
        );
        assert_eq!(MessageKind::Action.transport_class(), TransportClass::Small);
        let eval: Vec<_> = MessageKind::ALL
            .iter()
            .filter(|k| k.evaluation_only())
            .collect();
        assert_eq!(eval, vec![&MessageKind::TruePose]);
    }

    #[test]
    fn payload_trait_dispatches_to_the_right_codec() {
        let c = Counter { seq: 3, value: -4 };
        let bytes = Payload::to_bytes(&c).unwrap();
        assert_eq!(<Counter as Payload>::from_bytes(&bytes).unwrap(), c);
        // Bytes of one small type fed to another: a clear error, not a panic (Action has an enum tag
        // that Counter's bytes do not satisfy, or trailing bytes remain).
        assert!(<Action as Payload>::from_bytes(&[1, 0, 3, 200, 1]).is_err());
    }
}
