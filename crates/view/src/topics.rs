//! The view channels: one topic per kind of picture, each with one Foxglove schema.

use foxglove::Encode;
use foxglove::messages::{
    CameraCalibration, CompressedImage, FrameTransforms, Grid, Log, PointCloud, PoseInFrame,
    SceneUpdate,
};

/// Message encoding of every view channel (Foxglove's schemas are protobuf messages).
pub const VIEW_ENCODING: &str = "protobuf";

/// One view channel. The topics start with `/view/` (or are `/tf`, where Foxglove's 3D panel
/// looks for transforms), so they never collide with the pipeline's `node/output` channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum ViewTopic {
    /// The simulator's colour image, JPEG.
    Color,
    /// The depth image, colour-mapped to a PNG (near dark, far bright; no reading black).
    Depth,
    /// The camera's pinhole intrinsics, so the 3D panel can project the images.
    Calibration,
    /// The tracker's pose estimate of the camera in `world`.
    EstimatedPose,
    /// The true camera pose (evaluation only).
    TruePose,
    /// The transform tree: `world` → `camera` (estimated) and `world` → `camera_true`.
    Transforms,
    /// The occupancy grid on the floor (free 0, unknown 50, occupied 100).
    Occupancy,
    /// The Gaussian map's centres with their colours (decimated).
    Map,
    /// Frontier regions: a sphere per region, sized by its cell count, and its number.
    Frontiers,
    /// The planner's goal and the scorer's chosen path.
    Path,
    /// A Fisher replan's candidate poses (arrows, brighter for more EIG) and the paths scored.
    Candidates,
    /// Decisions in words: goals, LLM answers, Fisher choices, replans, lost tracking, episode end.
    Log,
}

impl ViewTopic {
    /// Every view channel, in the order they are declared in a recording.
    pub const ALL: [ViewTopic; 12] = [
        ViewTopic::Color,
        ViewTopic::Depth,
        ViewTopic::Calibration,
        ViewTopic::EstimatedPose,
        ViewTopic::TruePose,
        ViewTopic::Transforms,
        ViewTopic::Occupancy,
        ViewTopic::Map,
        ViewTopic::Frontiers,
        ViewTopic::Path,
        ViewTopic::Candidates,
        ViewTopic::Log,
    ];

    /// The channel's topic.
    pub fn topic(self) -> &'static str {
        match self {
            ViewTopic::Color => "/view/camera/color",
            ViewTopic::Depth => "/view/camera/depth",
            ViewTopic::Calibration => "/view/camera/calibration",
            ViewTopic::EstimatedPose => "/view/pose/estimated",
            ViewTopic::TruePose => "/view/pose/true",
            ViewTopic::Transforms => "/tf",
            ViewTopic::Occupancy => "/view/map/occupancy",
            ViewTopic::Map => "/view/map/gaussians",
            ViewTopic::Frontiers => "/view/planning/frontiers",
            ViewTopic::Path => "/view/planning/path",
            ViewTopic::Candidates => "/view/planning/candidates",
            ViewTopic::Log => "/view/log",
        }
    }

    /// The channel's Foxglove schema (name such as `foxglove.CompressedImage`, encoding
    /// `protobuf`, and the message's file descriptor set).
    pub fn schema(self) -> foxglove::Schema {
        let schema = match self {
            ViewTopic::Color | ViewTopic::Depth => CompressedImage::get_schema(),
            ViewTopic::Calibration => CameraCalibration::get_schema(),
            ViewTopic::EstimatedPose | ViewTopic::TruePose => PoseInFrame::get_schema(),
            ViewTopic::Transforms => FrameTransforms::get_schema(),
            ViewTopic::Occupancy => Grid::get_schema(),
            ViewTopic::Map => PointCloud::get_schema(),
            ViewTopic::Frontiers | ViewTopic::Path | ViewTopic::Candidates => {
                SceneUpdate::get_schema()
            }
            ViewTopic::Log => Log::get_schema(),
        };
        schema.expect("Foxglove's well-known messages always carry their schema")
    }

    /// The topic of a channel name, if it is a view channel.
    pub fn from_topic(topic: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.topic() == topic)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topics_are_unique_and_schemas_are_foxgloves_protobuf_ones() {
        let mut seen = std::collections::BTreeSet::new();
        for t in ViewTopic::ALL {
            assert!(seen.insert(t.topic()), "{} twice", t.topic());
            assert_eq!(ViewTopic::from_topic(t.topic()), Some(t));
            let s = t.schema();
            assert!(s.name.starts_with("foxglove."), "{}", s.name);
            assert_eq!(s.encoding, VIEW_ENCODING);
            assert!(!s.data.is_empty());
        }
        assert_eq!(ViewTopic::from_topic("sim/rgbd"), None);
    }
}
