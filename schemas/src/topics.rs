//! Canonical topics of the pipeline of SPEC §1 (`node/output`) and the message kind each carries.
//! Dataflow files may use other node ids; these are the names of the reference `dataflow.yaml`.

use crate::MessageKind;

/// A named topic and its message kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Topic {
    /// `node/output`.
    pub name: &'static str,
    /// What it carries.
    pub kind: MessageKind,
}

/// Simulator RGB-D frames (step 1).
pub const SIM_RGBD: Topic = Topic {
    name: "sim/rgbd",
    kind: MessageKind::RgbdFrame,
};
/// Simulator ground-truth pose (evaluation only).
pub const SIM_TRUE_POSE: Topic = Topic {
    name: "sim/true_pose",
    kind: MessageKind::TruePose,
};
/// Simulator episode progress.
pub const SIM_EPISODE: Topic = Topic {
    name: "sim/episode",
    kind: MessageKind::EpisodeStatus,
};
/// Tracker pose estimates (step 2).
pub const TRACKER_POSE: Topic = Topic {
    name: "tracker/pose",
    kind: MessageKind::PoseEstimate,
};
/// Mapper map snapshots (step 3).
pub const MAPPER_MAP: Topic = Topic {
    name: "mapper/map",
    kind: MessageKind::GaussianMap,
};
/// Occupancy grids (step 4).
pub const OCCUPANCY_GRID: Topic = Topic {
    name: "occupancy/grid",
    kind: MessageKind::OccupancyGrid,
};
/// Frontier regions (step 5).
pub const FRONTIER_REGIONS: Topic = Topic {
    name: "frontier/regions",
    kind: MessageKind::Frontiers,
};
/// LLM planner goal (step 6).
pub const PLANNER_GOAL: Topic = Topic {
    name: "planner/goal",
    kind: MessageKind::Goal,
};
/// LLM planner exchanges (step 6), for inspection.
pub const PLANNER_LLM: Topic = Topic {
    name: "planner/llm",
    kind: MessageKind::LlmExchange,
};
/// Fisher scorer path (step 7).
pub const SCORER_PATH: Topic = Topic {
    name: "scorer/path",
    kind: MessageKind::Path,
};
/// Follower action (step 8).
pub const FOLLOWER_ACTION: Topic = Topic {
    name: "follower/action",
    kind: MessageKind::Action,
};
/// Follower replan requests.
pub const FOLLOWER_REPLAN: Topic = Topic {
    name: "follower/replan",
    kind: MessageKind::ReplanRequest,
};

/// Every canonical topic.
pub const ALL: &[Topic] = &[
    SIM_RGBD,
    SIM_TRUE_POSE,
    SIM_EPISODE,
    TRACKER_POSE,
    MAPPER_MAP,
    OCCUPANCY_GRID,
    FRONTIER_REGIONS,
    PLANNER_GOAL,
    PLANNER_LLM,
    SCORER_PATH,
    FOLLOWER_ACTION,
    FOLLOWER_REPLAN,
];

#[cfg(test)]
mod tests {
    #[test]
    fn topic_names_are_unique_node_slash_output() {
        let mut names: Vec<_> = super::ALL.iter().map(|t| t.name).collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), super::ALL.len());
        assert!(super::ALL.iter().all(|t| t.name.split('/').count() == 2));
    }
}
