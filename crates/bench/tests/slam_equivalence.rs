//! One SLAM: the scripted loop (what `activemap bench slam` measures) and the `tracker` and
//! `mapper` operators of the pipeline, fed the same frames and actions with the same node
//! configs (the repository's `dataflow.yaml`, map lag included), give bit-identical poses and
//! maps. The operators are driven through their transport-free cores with every message
//! converted as on the wire (poses as `PoseEstimate`, maps through the shared-memory layout),
//! in the pipeline's lockstep order. Once as the flow is, once with the tracker's pose graph on,
//! whose corrections then travel in the estimates and move the mapper's Gaussians.

mod common;

use activemap_bench::slam_loop::{LoopConfig, run_loop_traced};
use activemap_operators::convert::{map_header, read_map, write_map};
use activemap_operators::mapper::Mapper;
use activemap_operators::tracker::Tracker;
use activemap_schemas::{ActionKind, PoseEstimate};
use activemap_splat::Gaussians;

/// The map as the tracker receives it from the mapper: through the wire layout (with the
/// Gaussians' ids, which the tracker does not read).
fn through_the_wire(map: &Gaussians<f32>, ids: &[u64], frame_id: u64) -> Gaussians<f32> {
    let header = map_header(map, frame_id, 0.0, None);
    let mut buf = vec![0u8; header.payload_len().unwrap()];
    write_map(&mut buf, header, map, ids).unwrap();
    read_map(&buf).unwrap().1
}

#[test]
fn the_scripted_loop_and_the_operators_give_bit_identical_poses_and_maps() {
    let corrections = equivalence(false);
    assert_eq!(corrections, 0, "no pose graph, no correction");
}

#[test]
fn with_the_pose_graph_too() {
    let corrections = equivalence(true);
    assert!(
        corrections > 0,
        "the loop must close: no correction travelled"
    );
}

/// Runs both and compares them; returns the number of keyframe corrections that travelled in
/// the estimates.
fn equivalence(pose_graph: bool) -> usize {
    let (mut tracker_config, mapper_config) = common::flow_slam_nodes();
    assert!(
        tracker_config.map_lag > 0,
        "the flow maps in the background"
    );
    tracker_config.pose_graph = pose_graph;
    let slam = activemap_operators::mapper::slam_config(&tracker_config, &mapper_config).unwrap();
    let mut config = LoopConfig::new(64, 90, slam);
    config.keep_trace = true;
    let (result, trace) = run_loop_traced(&config).unwrap();
    assert!(result.keyframes >= 4, "{result:?}");

    let mut tracker = Tracker::from_config(tracker_config).unwrap();
    let mut mapper = Mapper::from_config(mapper_config).unwrap();
    let mut estimates: Vec<PoseEstimate> = Vec::new();
    let mut last_map = Gaussians::new();
    for (k, frame) in trace.frames.iter().enumerate() {
        let k = k as u64;
        if k > 0 {
            tracker.add_action(k - 1, ActionKind::from(trace.actions[k as usize - 1]));
        }
        tracker.add_frame(k, frame.clone());
        mapper.add_frame(k, frame.clone());
        loop {
            for s in mapper.process_ready(false).unwrap() {
                tracker.set_map(s.frame_id, through_the_wire(&s.map, &s.ids, s.frame_id));
                last_map = (*s.map).clone();
            }
            let out = tracker.process_ready().unwrap();
            if let Some(e) = out.last() {
                assert_eq!(out.len(), 1);
                mapper.add_pose(e.clone()).unwrap();
                estimates.push(e.clone());
                break;
            }
        }
    }
    for s in mapper.process_ready(true).unwrap() {
        last_map = (*s.map).clone();
    }

    assert_eq!(estimates.len(), trace.estimates.len());
    for (wire, scripted) in estimates.iter().zip(&trace.estimates) {
        assert_eq!(wire.frame_id, scripted.frame_id);
        assert_eq!(
            wire.t_world_camera,
            activemap_operators::convert::pose_to_wire(&scripted.pose),
            "frame {}",
            wire.frame_id
        );
    }
    let bits = |g: &Gaussians<f32>| {
        let mut v: Vec<u32> = Vec::new();
        for i in 0..g.len() {
            v.extend(g.means[i].iter().map(|x| x.to_bits()));
            v.extend(g.sh_dc[i].iter().map(|x| x.to_bits()));
            v.extend(g.rotations[i].iter().map(|x| x.to_bits()));
            v.extend(g.log_scales[i].iter().map(|x| x.to_bits()));
            v.push(g.opacity_logits[i].to_bits());
        }
        v
    };
    assert_eq!(last_map.len(), trace.map.len());
    assert!(bits(&last_map) == bits(&trace.map), "the final maps differ");
    estimates.iter().map(|e| e.keyframe_corrections.len()).sum()
}
