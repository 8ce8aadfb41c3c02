//! A flat floor mapped from known poses (issue 33, item 6): the robot's camera (0.88 m up,
//! looking level, 90° FOV) sees a textured floor z = 0 at grazing angles, as in the house; after
//! a few keyframes mapped at the true poses the Gaussian centres (opacity-weighted median) lie
//! within 1 cm of the floor and the keyframes render above a PSNR floor.

use activemap_geometry::{Intrinsics, Isometry3, PlanarPose, camera_pose_from_planar};
use activemap_slam::{Frame, Mapper, MapperConfig};
use activemap_splat::{Camera, RenderOptions, render};

const SIDE: usize = 48;
const CAMERA_HEIGHT: f64 = 0.88;
/// Half the side of the floor square, metres; rays that miss it read no depth.
const FLOOR_HALF: f64 = 3.0;

/// The floor's colour at (x, y): 25 cm checks with a smooth ramp inside each.
fn floor_colour(x: f64, y: f64) -> [f32; 3] {
    let (i, j) = ((x / 0.25).floor() as i64, (y / 0.25).floor() as i64);
    let check = if (i + j).rem_euclid(2) == 0 {
        0.8
    } else {
        0.25
    };
    let ramp = (x / 0.25).rem_euclid(1.0) as f32 * 0.15;
    [check + ramp, 0.5, 1.0 - check]
}

/// The frame the camera at `pose` (`T_world_camera`) sees of the floor.
fn floor_frame(pose: &Isometry3<f64>) -> Frame {
    let k = Intrinsics::from_hfov(SIDE as u32, SIDE as u32, std::f64::consts::FRAC_PI_2);
    let mut rgb = Vec::with_capacity(SIDE * SIDE);
    let mut depth = Vec::with_capacity(SIDE * SIDE);
    for v in 0..SIDE {
        for u in 0..SIDE {
            let ray = k.unproject(u as f64, v as f64, 1.0); // camera frame, z = 1
            let origin = pose.translation.vector;
            let dir = pose.rotation * ray.coords;
            let t = -origin.z / dir.z; // z-depth of the hit, since ray.z = 1
            let hit = origin + dir * t;
            if dir.z < 0.0 && hit.x.abs() < FLOOR_HALF && hit.y.abs() < FLOOR_HALF {
                rgb.push(floor_colour(hit.x, hit.y));
                depth.push(t as f32);
            } else {
                rgb.push([0.0; 3]);
                depth.push(0.0);
            }
        }
    }
    Frame::new(k, rgb, depth, 0.0).unwrap()
}

/// Opacity-weighted median of the centres' heights above the floor, metres.
fn median_height(mapper: &Mapper) -> f64 {
    let map = mapper.map();
    let mut pairs: Vec<(f64, f64)> = (0..map.len())
        .map(|i| (f64::from(map.means[i][2]), map.opacity(i)))
        .collect();
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = pairs.iter().map(|p| p.1).sum();
    let mut cumulative = 0.0;
    for (z, w) in pairs {
        cumulative += w;
        if cumulative >= 0.5 * total {
            return z;
        }
    }
    f64::NAN
}

/// Maps the floor from `keyframes` known poses along a straight line with small turns.
fn map_floor(config: MapperConfig, keyframes: usize) -> (Mapper, Vec<Isometry3<f64>>) {
    let mut mapper = Mapper::new(config).unwrap();
    let poses: Vec<Isometry3<f64>> = (0..keyframes)
        .map(|k| {
            let yaw = 0.15 * ((k % 3) as f64 - 1.0);
            let planar = PlanarPose::new(-2.0 + 0.15 * k as f64, 0.05 * (k % 2) as f64, yaw);
            camera_pose_from_planar(&planar, 0.0, CAMERA_HEIGHT)
        })
        .collect();
    for pose in &poses {
        mapper
            .add_keyframe(floor_frame(pose), *pose, [0.0, 0.0])
            .unwrap();
    }
    (mapper, poses)
}

fn psnr(mapper: &Mapper, pose: &Isometry3<f64>) -> f64 {
    let frame = floor_frame(pose);
    let camera = Camera::from_world_pose(frame.intrinsics, pose);
    let out = render(mapper.map(), &camera, &RenderOptions::default()).unwrap();
    let mut sum = 0.0;
    for (r, t) in out.colour.iter().zip(&frame.rgb) {
        for c in 0..3 {
            sum += f64::from(r[c].clamp(0.0, 1.0) - t[c]).powi(2);
        }
    }
    -10.0 * (sum / (3 * frame.rgb.len()) as f64).log10()
}

/// With the default mapper settings: median centre height within 2 cm of the floor, PSNR of
/// the last keyframe's render (the sky reads black in both) at least 16 dB. Measured at 48², 8
/// keyframes, with the default discs: 20 iterations per keyframe (the default) −1.56 cm and
/// 18.92 dB; 10 iterations −0.46 cm and 17.35 dB; 30 iterations −2.87 cm and 19.40 dB (more
/// optimisation sinks this floor while fitting it better; in closed loop 20 iterations improved
/// accuracy, depth MAE and PSNR on every house, docs/src/slam.md). Earlier, at 10 iterations:
/// round insertion with the isotropic regulariser −0.51 cm, 16.99 dB; at 64², 12 keyframes and
/// 30 iterations the round floor sank to −3.9 cm, and α = 0.5 sank it to −3.2 cm with discs. So
/// this guards against more optimisation or more depth weight sinking it further.
#[test]
fn a_floor_mapped_from_known_poses_lies_on_the_floor() {
    let (mapper, poses) = map_floor(MapperConfig::default(), 8);
    let median = median_height(&mapper);
    let psnr = psnr(&mapper, poses.last().unwrap());
    eprintln!(
        "floor: {} Gaussians, median height {:.2} cm, PSNR {psnr:.2} dB",
        mapper.map().len(),
        median * 100.0
    );
    assert!(median.abs() <= 0.02, "median height {median}");
    assert!(psnr >= 16.0, "{psnr}");
}
