//! Entry point of the `payload_views` fuzz target (`fuzz/`) and its regression replay test. Not
//! part of the public API.

use crate::kind::{MessageKind, Payload};
use crate::messages::*;
use crate::{GaussianMap, GaussianMapView, OccupancyGrid, OccupancyGridView, RgbdFrame};
use crate::{RgbdFrameView, SchemaError};

/// Reads a payload: the first byte picks the message kind (modulo the number of kinds), the
/// rest is the payload. Large kinds are parsed as a view, every section read, and decoded to
/// the owned message; small kinds are decoded.
pub fn payload(data: &[u8]) {
    let Some((&pick, bytes)) = data.split_first() else {
        return;
    };
    let kind = MessageKind::ALL[pick as usize % MessageKind::ALL.len()];
    match kind {
        MessageKind::RgbdFrame => {
            if let Ok(view) = RgbdFrameView::parse(bytes) {
                let _ = view.depth();
                let _ = view.to_owned_frame();
            }
            let _ = RgbdFrame::from_bytes(bytes);
        }
        MessageKind::GaussianMap => {
            if let Ok(view) = GaussianMapView::parse(bytes) {
                let _ = (view.means(), view.colors(), view.rotations());
                let _ = (view.opacities(), view.log_scales(), view.ids());
            }
            let _ = GaussianMap::from_bytes(bytes);
        }
        MessageKind::OccupancyGrid => {
            if let Ok(view) = OccupancyGridView::parse(bytes) {
                let _ = view.header.payload_len();
            }
            let _ = OccupancyGrid::from_bytes(bytes);
        }
        MessageKind::Action => small::<Action>(bytes),
        MessageKind::PoseEstimate => small::<PoseEstimate>(bytes),
        MessageKind::TruePose => small::<TruePose>(bytes),
        MessageKind::Frontiers => small::<Frontiers>(bytes),
        MessageKind::Goal => small::<Goal>(bytes),
        MessageKind::Path => small::<Path>(bytes),
        MessageKind::ReplanRequest => small::<ReplanRequest>(bytes),
        MessageKind::EpisodeStatus => small::<EpisodeStatus>(bytes),
        MessageKind::FisherReport => small::<FisherReport>(bytes),
        MessageKind::LlmExchange => small::<LlmExchange>(bytes),
        MessageKind::Counter => small::<Counter>(bytes),
    }
}

/// Decodes a small message, and encodes it again if it decoded.
fn small<T: Payload>(bytes: &[u8]) {
    let decoded: Result<T, SchemaError> = T::from_bytes(bytes);
    if let Ok(message) = decoded {
        let _ = message.to_bytes();
    }
}
