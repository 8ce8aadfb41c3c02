use super::*;
use activemap_schemas::{
    FisherCandidate, FisherPath, FisherTimings, FrontierRegion, GaussianMap, OccupancyGrid,
    PlanarPose2, ReplanReason, RgbdFrame, RgbdFrameHeader,
};
use foxglove::Decode;

const T0: u64 = 1_800_000_000_000_000_000;

fn frame(frame_id: u64, w: u32, h: u32) -> Vec<u8> {
    let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i % 200) as u8).collect();
    let depth: Vec<f32> = (0..w * h).map(|i| 0.5 + (i % w) as f32 * 0.1).collect();
    RgbdFrame {
        header: RgbdFrameHeader::new(
            frame_id,
            frame_id as f64 * 0.1,
            [40.0, 41.0, 16.0, 12.0],
            w,
            h,
        ),
        rgb,
        depth,
    }
    .encode()
    .unwrap()
}

fn pose(frame_id: u64, status: TrackingStatus) -> Vec<u8> {
    PoseEstimate {
        frame_id,
        stamp: 0.0,
        t_world_camera: activemap_schemas::Pose {
            translation: [1.0, 2.0, 0.8],
            rotation_xyzw: [0.5, -0.5, 0.5, -0.5],
        },
        status,
        residual_rgb: 0.0,
        residual_depth: 0.0,
        iterations: 3,
        graph_anchor: None,
        keyframe_corrections: Vec::new(),
        lost_reason: (status == TrackingStatus::Lost)
            .then_some(activemap_schemas::LostReason::LowOverlap { fraction: 0.1 }),
        relocalised: None,
    }
    .encode()
}

fn map(frame_id: u64, keyframe: u64, n: usize) -> Vec<u8> {
    GaussianMap {
        stamp: 0.0,
        frame_id,
        keyframe_id: Some(keyframe),
        means: (0..3 * n).map(|i| i as f32).collect(),
        colors: (0..3 * n).map(|i| [0.0, 0.5, 1.0][i % 3]).collect(),
        rotations: (0..n).flat_map(|_| [1.0, 0.0, 0.0, 0.0]).collect(),
        opacities: vec![1.0; n],
        log_scales: vec![-3.0; 3 * n],
        ids: (0..n as u64).collect(),
    }
    .encode()
    .unwrap()
}

fn grid(frame_id: u64) -> Vec<u8> {
    OccupancyGrid {
        stamp: 0.0,
        frame_id,
        origin: [-1.0, 2.5],
        resolution: 0.1,
        width: 3,
        height: 2,
        cells: vec![0, 1, 2, 2, 1, 0],
    }
    .encode()
    .unwrap()
}

fn only(out: Vec<ViewMessage>, topic: ViewTopic) -> ViewMessage {
    let mut found: Vec<_> = out.into_iter().filter(|m| m.topic == topic).collect();
    assert_eq!(found.len(), 1, "{topic:?}");
    found.pop().unwrap()
}

fn ns(t: Option<Timestamp>) -> u64 {
    let t = t.expect("timestamp");
    t.sec() as u64 * 1_000_000_000 + t.nsec() as u64
}

#[test]
fn a_frame_gives_its_images_and_calibration_and_its_pose_shares_the_frame_time() {
    let mut c = ViewConverter::new(ViewSettings::default());
    let out = c
        .convert("sim/rgbd", MessageKind::RgbdFrame, &frame(7, 32, 24), T0)
        .unwrap();
    let color =
        CompressedImage::decode(only(out.clone(), ViewTopic::Color).data.as_slice()).unwrap();
    assert_eq!(color.format, "jpeg");
    assert_eq!(color.frame_id, CAMERA_FRAME);
    let img = image::load_from_memory(&color.data).unwrap();
    assert_eq!((img.width(), img.height()), (32, 24));
    let depth =
        CompressedImage::decode(only(out.clone(), ViewTopic::Depth).data.as_slice()).unwrap();
    assert_eq!(depth.format, "png");
    let d = image::load_from_memory(&depth.data).unwrap().to_rgb8();
    assert_eq!(d.get_pixel(5, 3).0, images::depth_color(1.0, 8.0));
    let cal = CameraCalibration::decode(only(out, ViewTopic::Calibration).data.as_slice()).unwrap();
    assert_eq!(cal.k, vec![40.0, 0.0, 16.0, 0.0, 41.0, 12.0, 0.0, 0.0, 1.0]);
    assert_eq!((cal.width, cal.height), (32, 24));

    // The pose of frame 7 arrives later and is stamped with the frame's time.
    let later = T0 + 25_000_000;
    let out = c
        .convert(
            "tracker/pose",
            MessageKind::PoseEstimate,
            &pose(7, TrackingStatus::Ok),
            later,
        )
        .unwrap();
    let p =
        PoseInFrame::decode(only(out.clone(), ViewTopic::EstimatedPose).data.as_slice()).unwrap();
    assert_eq!(ns(p.timestamp), T0);
    assert_eq!(p.frame_id, WORLD_FRAME);
    let pos = p.pose.unwrap().position.unwrap();
    assert_eq!((pos.x, pos.y, pos.z), (1.0, 2.0, 0.8));
    let tf_msg = only(out.clone(), ViewTopic::Transforms);
    assert_eq!(tf_msg.log_time_ns, later);
    let tf = FrameTransforms::decode(tf_msg.data.as_slice()).unwrap();
    assert_eq!(tf.transforms.len(), 1);
    let tf = &tf.transforms[0];
    assert_eq!(
        (tf.parent_frame_id.as_str(), tf.child_frame_id.as_str()),
        (WORLD_FRAME, CAMERA_FRAME)
    );
    assert_eq!(ns(tf.timestamp), T0);
    let q = tf.rotation.unwrap();
    assert_eq!((q.x, q.y, q.z, q.w), (0.5, -0.5, 0.5, -0.5));
    // The first pose, tracked fine, says nothing in the log; losing tracking does.
    assert!(out.iter().all(|m| m.topic != ViewTopic::Log));
    let out = c
        .convert(
            "tracker/pose",
            MessageKind::PoseEstimate,
            &pose(8, TrackingStatus::Lost),
            later,
        )
        .unwrap();
    let log = Log::decode(only(out, ViewTopic::Log).data.as_slice()).unwrap();
    assert_eq!(log.level, log::Level::Warning as i32);
    assert_eq!(log.name, "tracker");
    assert!(
        log.message.contains("frame 8")
            && log
                .message
                .contains("Lost: only 10 % of the depth pixels overlap the map"),
        "{}",
        log.message
    );
    // A pose of a frame never seen takes its arrival time.
    let out = c
        .convert(
            "tracker/pose",
            MessageKind::PoseEstimate,
            &pose(99, TrackingStatus::Lost),
            later,
        )
        .unwrap();
    let p = PoseInFrame::decode(only(out, ViewTopic::EstimatedPose).data.as_slice()).unwrap();
    assert_eq!(ns(p.timestamp), later);
}

#[test]
fn the_grid_keeps_its_geometry_and_maps_cells_and_is_thinned_in_time() {
    let mut c = ViewConverter::new(ViewSettings::default());
    let out = c
        .convert("occupancy/grid", MessageKind::OccupancyGrid, &grid(10), T0)
        .unwrap();
    let g = Grid::decode(only(out, ViewTopic::Occupancy).data.as_slice()).unwrap();
    assert_eq!(g.column_count, 3);
    assert_eq!((g.row_stride, g.cell_stride), (3, 1));
    assert_eq!(g.data.as_ref(), &[0, 100, 50, 50, 100, 0]);
    let origin = g.pose.unwrap().position.unwrap();
    assert_eq!((origin.x, origin.y), (-1.0, 2.5));
    assert_eq!(g.cell_size.unwrap().x, 0.1);
    assert_eq!(g.fields[0].r#type, NumericType::Uint8 as i32);
    // Every 5th frame only.
    for (frame, shown) in [
        (11, false),
        (14, false),
        (15, true),
        (16, false),
        (20, true),
    ] {
        let out = c
            .convert(
                "occupancy/grid",
                MessageKind::OccupancyGrid,
                &grid(frame),
                T0,
            )
            .unwrap();
        assert_eq!(out.len(), usize::from(shown), "frame {frame}");
    }
}

#[test]
fn the_map_cloud_is_decimated_coloured_and_sent_only_after_a_new_keyframe() {
    let settings = ViewSettings {
        max_map_points: 100,
        map_every_frames: 10,
        ..ViewSettings::default()
    };
    let mut c = ViewConverter::new(settings);
    let out = c
        .convert("mapper/map", MessageKind::GaussianMap, &map(3, 1, 250), T0)
        .unwrap();
    let cloud = PointCloud::decode(only(out, ViewTopic::Map).data.as_slice()).unwrap();
    assert_eq!(cloud.point_stride, 16);
    // 250 Gaussians, at most 100 points: every 3rd, 84 points.
    assert_eq!(cloud.data.len(), 84 * 16);
    let point = |k: usize| {
        let b = &cloud.data[k * 16..k * 16 + 16];
        let f = |o: usize| f32::from_le_bytes(b[o..o + 4].try_into().unwrap());
        ([f(0), f(4), f(8)], [b[12], b[13], b[14], b[15]])
    };
    assert_eq!(point(1), ([9.0, 10.0, 11.0], [0, 128, 255, 255]));
    let names: Vec<_> = cloud.fields.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["x", "y", "z", "red", "green", "blue", "alpha"]);
    // Same keyframe: nothing; a new keyframe too soon: nothing; later: a cloud.
    for (frame, keyframe, shown) in [(20, 1, false), (8, 2, false), (13, 2, true), (30, 2, false)] {
        let out = c
            .convert(
                "mapper/map",
                MessageKind::GaussianMap,
                &map(frame, keyframe, 250),
                T0,
            )
            .unwrap();
        assert_eq!(
            out.len(),
            usize::from(shown),
            "frame {frame} keyframe {keyframe}"
        );
    }
}

#[test]
fn planning_messages_become_markers_and_log_lines() {
    let mut c = ViewConverter::new(ViewSettings::default());
    let frontiers = Frontiers {
        frame_id: 4,
        stamp: 0.0,
        regions: vec![FrontierRegion {
            id: 0,
            size_cells: 40,
            centroid: [1.0, 1.0],
            closest_reachable_cell: [3, 3],
            path_distance_m: 2.0,
            anchor: [1.1, 0.9],
        }],
    };
    let out = c
        .convert(
            "frontier/regions",
            MessageKind::Frontiers,
            &frontiers.encode(),
            T0,
        )
        .unwrap();
    let scene = SceneUpdate::decode(only(out, ViewTopic::Frontiers).data.as_slice()).unwrap();
    assert_eq!(scene.entities.len(), 1);
    assert_eq!(scene.entities[0].spheres.len(), 1);
    assert_eq!(scene.entities[0].texts[0].text, "0");

    let goal = Goal {
        frame_id: 4,
        target: -1,
        focus: [2.0, 3.0],
    };
    let out = c
        .convert("planner/goal", MessageKind::Goal, &goal.encode(), T0)
        .unwrap();
    let log = Log::decode(only(out.clone(), ViewTopic::Log).data.as_slice()).unwrap();
    assert!(log.message.contains("refine"), "{}", log.message);
    assert_eq!(log.name, "planner");
    let scene = SceneUpdate::decode(only(out, ViewTopic::Path).data.as_slice()).unwrap();
    assert_eq!(scene.entities[0].id, "goal");

    let path = Path {
        frame_id: 4,
        waypoints: vec![
            PlanarPose2 {
                x: 0.0,
                y: 0.0,
                yaw: 0.0,
            },
            PlanarPose2 {
                x: 1.0,
                y: 0.5,
                yaw: 1.0,
            },
        ],
        objective: 2.5,
    };
    let out = c
        .convert("scorer/path", MessageKind::Path, &path.encode(), T0)
        .unwrap();
    let scene = SceneUpdate::decode(only(out, ViewTopic::Path).data.as_slice()).unwrap();
    let line = &scene.entities[0].lines[0];
    assert_eq!(line.points.len(), 2);
    assert_eq!((line.points[1].x, line.points[1].y), (1.0, 0.5));
    assert_eq!(scene.entities[0].arrows.len(), 1);

    let report = FisherReport {
        frame_id: 4,
        refine: false,
        focus: Some([2.0, 3.0]),
        candidates: vec![
            FisherCandidate {
                x: 1.0,
                y: 1.0,
                yaw: 0.3,
                eig: 5.0
            };
            3
        ],
        paths: vec![FisherPath {
            goal: PlanarPose2 {
                x: 1.0,
                y: 1.0,
                yaw: 0.3,
            },
            waypoints: 4,
            actions: 30,
            scored_steps: vec![5, 10],
            eig: vec![2.0, 1.0],
            c_local: vec![-3.0, -4.0],
            objective: -12.5,
        }],
        chosen: 0,
        gaussians: 1000,
        unknown_gaussians: 200,
        model_reused: true,
        note: None,
        timings: FisherTimings::default(),
        fallback: None,
    };
    let out = c
        .convert(
            "scorer/report",
            MessageKind::FisherReport,
            &report.encode(),
            T0,
        )
        .unwrap();
    let scene =
        SceneUpdate::decode(only(out.clone(), ViewTopic::Candidates).data.as_slice()).unwrap();
    assert_eq!(scene.entities[0].arrows.len(), 4);
    let log = Log::decode(only(out, ViewTopic::Log).data.as_slice()).unwrap();
    assert!(
        log.message.contains("chose path 0") && log.message.contains("-12.5"),
        "{}",
        log.message
    );

    let replan = ReplanRequest {
        frame_id: 5,
        reason: ReplanReason::Blocked,
    };
    let out = c
        .convert(
            "follower/replan",
            MessageKind::ReplanRequest,
            &replan.encode(),
            T0,
        )
        .unwrap();
    let log = Log::decode(only(out, ViewTopic::Log).data.as_slice()).unwrap();
    assert!(log.message.contains("Blocked"), "{}", log.message);

    let status = |step, state| {
        EpisodeStatus {
            step,
            max_steps: 10,
            state,
            message: String::new(),
        }
        .encode()
    };
    let out = c
        .convert(
            "sim/episode",
            MessageKind::EpisodeStatus,
            &status(1, EpisodeState::Running),
            T0,
        )
        .unwrap();
    assert!(out.is_empty());
    let out = c
        .convert(
            "sim/episode",
            MessageKind::EpisodeStatus,
            &status(10, EpisodeState::Finished),
            T0,
        )
        .unwrap();
    let log = Log::decode(only(out, ViewTopic::Log).data.as_slice()).unwrap();
    assert!(
        log.message.contains("Finished at step 10"),
        "{}",
        log.message
    );
}

#[test]
fn a_bad_payload_is_an_error_naming_its_channel_and_an_empty_one_is_nothing() {
    let mut c = ViewConverter::new(ViewSettings::default());
    let err = c
        .convert("sim/rgbd", MessageKind::RgbdFrame, &[1, 2, 3], T0)
        .unwrap_err();
    assert!(
        err.to_string().contains("sim/rgbd") && err.to_string().contains("RgbdFrame"),
        "{err}"
    );
    assert!(
        c.convert("sim/rgbd", MessageKind::RgbdFrame, &[], T0)
            .unwrap()
            .is_empty()
    );
    assert!(
        c.convert("x/counter", MessageKind::Counter, &[0, 1], T0)
            .unwrap()
            .is_empty()
    );
}
