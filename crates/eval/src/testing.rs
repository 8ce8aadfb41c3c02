//! Test fixtures: small synthetic run folders on a one-room procedural house, laid out as the
//! `evaluator` operator writes them.

use crate::run_eval::{SceneSpec, scene_simulator, start_from_world};
use crate::run_folder::{CoverageRow, RunFolder, Summary};
use activemap_geometry::tum::Trajectory;
use activemap_geometry::{Intrinsics, Isometry3};
use activemap_sim::{Action, Simulator};
use activemap_splat::Gaussians;
use std::path::Path;

/// A one-room house, small enough for fast tests.
pub fn small_house() -> SceneSpec {
    SceneSpec {
        max_rooms: Some(1),
        max_area: Some(12.0),
        ..SceneSpec::new("house:3")
    }
}

/// The simulator of [`small_house`] with a `size`² camera at 90°.
pub fn simulator(size: u32) -> Simulator {
    scene_simulator(
        &small_house(),
        Intrinsics::from_hfov(size, size, std::f64::consts::FRAC_PI_2),
        activemap_geometry::RobotModel::default(),
    )
    .unwrap()
}

/// What map a synthetic run holds.
pub enum MapKind {
    /// No Gaussian.
    Empty,
    /// Opaque grey Gaussians at mesh surface samples, in the run's map (start) frame.
    SurfaceInMapFrame,
    /// The same Gaussians left in the world frame (a frame bug the evaluation must expose).
    SurfaceInWorldFrame,
}

/// Writes a run folder into `dir`: 72 true poses (three turns then a forward step, over and
/// over from the house's start: a 270° sweep, so the surface fusion's trajectory views see a
/// good part of the room), the estimate = the truth in the map frame (exact), a map of `kind`,
/// `coverage.csv` ending at 0.42 and `summary.json` naming the scene.
pub fn write_run(dir: &Path, kind: MapKind) {
    let mut sim = simulator(16);
    let floor_z = sim.navigation().floor_z();
    let mut truth = Trajectory::default();
    let actions = [
        Action::TurnLeft,
        Action::TurnLeft,
        Action::TurnLeft,
        Action::Forward,
    ];
    for k in 0..72 {
        truth.push(k as f64 * 0.1, sim.true_pose());
        sim.step(actions[k % actions.len()]);
    }
    let to_map = start_from_world(&truth.poses[0], floor_z);
    let mut estimate = Trajectory::default();
    for (t, p) in truth.stamps.iter().zip(&truth.poses) {
        estimate.push(*t, to_map * p);
    }
    let run = RunFolder::new(dir);
    run.write_trajectory(RunFolder::TRAJECTORY_TRUE, &truth)
        .unwrap();
    run.write_trajectory(RunFolder::TRAJECTORY_EST, &estimate)
        .unwrap();
    let mut map = Gaussians::<f32>::new();
    let frame = match kind {
        MapKind::Empty => None,
        MapKind::SurfaceInMapFrame => Some(to_map),
        MapKind::SurfaceInWorldFrame => Some(Isometry3::identity()),
    };
    if let Some(frame) = frame {
        // Flat discs (3 cm across, 3 mm thick) lying in the surface, as a good map's are.
        for s in activemap_sim::ground_truth::oriented_surface_samples(sim.scene(), 60_000, 11) {
            let q = frame * s.point;
            let normal = frame.rotation * s.normal;
            let r = nalgebra::UnitQuaternion::rotation_between(&nalgebra::Vector3::z(), &normal)
                .unwrap_or_else(|| {
                    nalgebra::UnitQuaternion::from_axis_angle(
                        &nalgebra::Vector3::x_axis(),
                        std::f64::consts::PI,
                    )
                });
            let w = r.quaternion();
            map.push(
                [q.x, q.y, q.z],
                [0.5, 0.5, 0.5],
                [w.w, w.i, w.j, w.k],
                0.99,
                [0.03, 0.03, 0.003],
            );
        }
    }
    run.write_map(&map).unwrap();
    let row = |step, coverage| CoverageRow { step, coverage };
    run.write_coverage(&[row(1, 0.1), row(5, 0.3), row(11, 0.42)])
        .unwrap();
    run.write_summary(&Summary {
        steps: 12,
        coverage: Some(0.42),
        ate_m: Some(0.0),
        path_length_m: 0.3,
        episode: "Running at step 12: synthetic".into(),
        map_gaussians: map.len(),
        scene: Some("house:3".into()),
        max_rooms: Some(1),
        max_area: Some(12.0),
        ..Summary::default()
    })
    .unwrap();
}

/// A scene of axis-aligned boxes `[lo, hi]` (all six faces, one grey material), for analytic
/// tests of what can be seen.
pub fn box_scene(boxes: &[([f32; 3], [f32; 3])]) -> activemap_sim::Scene {
    use activemap_sim::{Material, Scene, Triangle, Vertex};
    let mut scene = Scene {
        name: "boxes".into(),
        materials: vec![Material {
            name: "grey".into(),
            base_color: [0.5; 3],
            texture: None,
        }],
        ..Scene::default()
    };
    for &(lo, hi) in boxes {
        // Each face as (axis, side): its four corners in order around the face.
        for axis in 0..3 {
            for side in [lo[axis], hi[axis]] {
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let corners = [
                    (lo[u], lo[v]),
                    (hi[u], lo[v]),
                    (hi[u], hi[v]),
                    (lo[u], hi[v]),
                ];
                let base = scene.vertices.len() as u32;
                for (cu, cv) in corners {
                    let mut position = [0f32; 3];
                    position[axis] = side;
                    position[u] = cu;
                    position[v] = cv;
                    scene.vertices.push(Vertex {
                        position,
                        uv: [0.0; 2],
                        color: [1.0; 3],
                    });
                }
                for t in [[0, 1, 2], [0, 2, 3]] {
                    scene.triangles.push(Triangle {
                        vertices: t.map(|k| base + k),
                        material: 0,
                    });
                }
            }
        }
    }
    scene
}
