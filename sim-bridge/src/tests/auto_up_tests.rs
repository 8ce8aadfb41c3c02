//! `up_axis: auto`: synthetic rooms tilted up to 80° about seeded random axes, in y-down and
//! z-up files, with and without vertex noise, levelled on their floor even where a wall is
//! larger than the floor; ambiguous scans refused with candidates that each level in one step;
//! the furnished house and a procedural house placed as with their known up axis.

use super::fixtures::{facing_quad as quad, flat, write_obj};
use crate::load::{LoadOptions, load_scene};
use crate::scene::Scene;
use crate::simulator::{SimConfig, Simulator};
use crate::{Floor, Placement, SceneSpec, SimError, Transform, UpAxis};
use nalgebra::{Rotation3, Unit, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use std::path::Path;

fn vec3(p: [f32; 3]) -> Vector3<f64> {
    Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    (a.dot(b) / (a.norm() * b.norm()))
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

/// The faces of the box [lo, hi] facing out, without its bottom (a piece of furniture on the
/// floor, as a scan sees it).
fn furniture(s: &mut Scene, lo: [f32; 3], hi: [f32; 3], m: u32) {
    let (a, b) = (lo, hi);
    quad(
        s,
        [
            [a[0], a[1], b[2]],
            [b[0], a[1], b[2]],
            [b[0], b[1], b[2]],
            [a[0], b[1], b[2]],
        ],
        [0.0, 0.0, 1.0],
        m,
    );
    quad(
        s,
        [
            [a[0], a[1], a[2]],
            [a[0], b[1], a[2]],
            [a[0], b[1], b[2]],
            [a[0], a[1], b[2]],
        ],
        [-1.0, 0.0, 0.0],
        m,
    );
    quad(
        s,
        [
            [b[0], a[1], a[2]],
            [b[0], b[1], a[2]],
            [b[0], b[1], b[2]],
            [b[0], a[1], b[2]],
        ],
        [1.0, 0.0, 0.0],
        m,
    );
    quad(
        s,
        [
            [a[0], a[1], a[2]],
            [b[0], a[1], a[2]],
            [b[0], a[1], b[2]],
            [a[0], a[1], b[2]],
        ],
        [0.0, -1.0, 0.0],
        m,
    );
    quad(
        s,
        [
            [a[0], b[1], a[2]],
            [b[0], b[1], a[2]],
            [b[0], b[1], b[2]],
            [a[0], b[1], b[2]],
        ],
        [0.0, 1.0, 0.0],
        m,
    );
}

/// What a synthetic room holds.
#[derive(Clone, Copy)]
struct Room {
    /// Inner size x, y, height, metres.
    size: [f32; 3],
    walls: bool,
    ceiling: bool,
    furnished: bool,
}

/// The materials of a room's floor and of its bed top (for checking heights after placement).
struct Marks {
    floor: u32,
    bed_top: u32,
}

/// A room in the world frame (floor at z = 0, faces seen from inside), every face split 3
/// times: a floor, walls, an optional ceiling, and a bed (top at 0.5 m), a table (0.75 m)
/// and a shelf (1.8 m).
fn room(r: Room) -> (Scene, Marks) {
    let mut s = Scene {
        name: "room".into(),
        ..Scene::default()
    };
    let [x, y, h] = r.size;
    let floor = flat(&mut s, [0.4; 3]);
    let wall = flat(&mut s, [0.8; 3]);
    let bed_top = flat(&mut s, [0.6, 0.2, 0.2]);
    let furn = flat(&mut s, [0.5, 0.3, 0.1]);
    quad(
        &mut s,
        [[0.0, 0.0, 0.0], [x, 0.0, 0.0], [x, y, 0.0], [0.0, y, 0.0]],
        [0.0, 0.0, 1.0],
        floor,
    );
    if r.ceiling {
        quad(
            &mut s,
            [[0.0, 0.0, h], [x, 0.0, h], [x, y, h], [0.0, y, h]],
            [0.0, 0.0, -1.0],
            wall,
        );
    }
    if r.walls {
        quad(
            &mut s,
            [[0.0, 0.0, 0.0], [x, 0.0, 0.0], [x, 0.0, h], [0.0, 0.0, h]],
            [0.0, 1.0, 0.0],
            wall,
        );
        quad(
            &mut s,
            [[0.0, y, 0.0], [x, y, 0.0], [x, y, h], [0.0, y, h]],
            [0.0, -1.0, 0.0],
            wall,
        );
        quad(
            &mut s,
            [[0.0, 0.0, 0.0], [0.0, y, 0.0], [0.0, y, h], [0.0, 0.0, h]],
            [1.0, 0.0, 0.0],
            wall,
        );
        quad(
            &mut s,
            [[x, 0.0, 0.0], [x, y, 0.0], [x, y, h], [x, 0.0, h]],
            [-1.0, 0.0, 0.0],
            wall,
        );
    }
    if r.furnished {
        furniture(&mut s, [0.2, 0.3, 0.0], [1.6, 2.3, 0.5], furn); // bed
        let n = s.triangles.len();
        s.triangles[n - 10].material = bed_top;
        s.triangles[n - 9].material = bed_top;
        furniture(
            &mut s,
            [x - 1.2, y - 1.6, 0.0],
            [x - 0.4, y - 0.4, 0.75],
            furn,
        ); // table
        if r.walls {
            furniture(&mut s, [x - 0.6, 0.2, 0.0], [x - 0.2, 1.2, 1.8], furn); // shelf
        }
    }
    (s.subdivided(3), Marks { floor, bed_top })
}

/// The long narrow room of the tests: a 2.4 m × 7 m floor (16.8 m²) under 3.2 m walls, each
/// long wall (22.4 m²) larger than the floor.
const NARROW: [f32; 3] = [2.4, 7.0, 3.2];

/// A seeded random unit axis, uniform on the sphere.
fn random_axis(rng: &mut impl Rng) -> Unit<Vector3<f64>> {
    loop {
        let v = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        if (0.1..1.0).contains(&v.norm()) {
            return Unit::new_normalize(v);
        }
    }
}

/// `scene` moved into a file's frame: tilted by `tilt`, offset, written with up axis `up`,
/// every vertex moved by a seeded uniform ±`noise` metres.
fn as_file(scene: &Scene, tilt: &Rotation3<f64>, up: UpAxis, noise: f32, seed: u64) -> Scene {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let offset = Vector3::new(0.7, -1.3, 0.4);
    let mut out = scene.clone();
    for v in &mut out.vertices {
        let w = tilt * vec3(v.position) + offset;
        let mut f = up.from_world([w.x as f32, w.y as f32, w.z as f32]);
        if noise > 0.0 {
            for c in &mut f {
                *c += rng.random_range(-noise..noise);
            }
        }
        v.position = f;
    }
    out
}

fn auto() -> Placement {
    Placement {
        up_axis: Some(UpAxis::Auto),
        floor: Floor::Auto,
        ..Placement::default()
    }
}

/// Mean and largest |z| of the vertices of the triangles of `material`.
fn heights(scene: &Scene, material: u32) -> (f64, f64) {
    let zs: Vec<f64> = scene
        .triangles
        .iter()
        .filter(|t| t.material == material)
        .flat_map(|t| scene.corners(t).map(|p| p.z))
        .collect();
    let mean = zs.iter().sum::<f64>() / zs.len() as f64;
    (mean, zs.iter().fold(0.0, |m, z| z.abs().max(m)))
}

#[test]
fn tilted_rooms_level_on_their_floor_in_y_down_and_z_up_files() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(37);
    let cases = 16;
    let mut worst = 0.0f64;
    for k in 0..cases {
        let angle = 80.0 * k as f64 / (cases - 1) as f64;
        let tilt = Rotation3::from_axis_angle(&random_axis(&mut rng), angle.to_radians());
        let up = if k % 2 == 0 { UpAxis::NegY } else { UpAxis::Z };
        let noise = if k % 4 < 2 { 0.0 } else { 0.006 };
        let r = Room {
            size: NARROW,
            walls: true,
            ceiling: k % 3 == 0,
            furnished: true,
        };
        let (truth, marks) = room(r);
        let mut scan = as_file(&truth, &tilt, up, noise, k);
        let (report, warnings) = auto().apply(&mut scan).unwrap_or_else(|e| {
            panic!("case {k} ({angle:.1}° in a {up} file, noise {noise}): {e}")
        });
        assert!(warnings.is_empty(), "{warnings:?}");
        let l = report.levelling.expect("levelled");
        // The true up in the file's frame, after the placement.
        let true_up = vec3(up.from_world({
            let u = tilt * Vector3::z();
            [u.x as f32, u.y as f32, u.z as f32]
        }));
        let residual = angle_deg(&(l.transform.isometry.rotation * true_up), &Vector3::z());
        let (floor_mean, floor_max) = heights(&scan, marks.floor);
        let (bed_mean, _) = heights(&scan, marks.bed_top);
        eprintln!(
            "case {k}: {angle:5.1}° in a {up:>2} file, noise {noise}, ceiling {}: residual \
             {residual:.3}°, floor at {:.1} mm (worst {:.1} mm), bed top at {bed_mean:.3} m\n  {report}",
            r.ceiling,
            floor_mean * 1e3,
            floor_max * 1e3
        );
        assert!(residual <= 0.5, "case {k}: residual tilt {residual}°");
        assert!(
            floor_mean.abs() < 0.005,
            "case {k}: floor at {floor_mean} m"
        );
        assert!(
            floor_max < 0.02,
            "case {k}: a floor vertex at {floor_max} m"
        );
        assert!(
            (bed_mean - 0.5).abs() < 0.01,
            "case {k}: bed top at {bed_mean} m"
        );
        assert_eq!(scan.floor_z, Some(0.0));
        let d = report.auto_up.clone().expect("decision");
        assert!(
            (d.chosen.area - 16.8).abs() < 0.3,
            "case {k}: floor {} m²",
            d.chosen.area
        );
        let text = report.to_string();
        assert!(
            text.contains("up axis auto") && text.contains("runner-up"),
            "case {k}: {text}"
        );
        worst = worst.max(residual);
    }
    eprintln!("worst residual tilt {worst:.3}°");
}

#[test]
fn the_report_names_the_axis_and_the_suggested_placement_reproduces_it() {
    // A y-down scan pitched 34° about the camera's x axis, as in the issue.
    let (truth, marks) = room(Room {
        size: [3.0, 3.5, 2.5],
        walls: true,
        ceiling: false,
        furnished: true,
    });
    let tilt = Rotation3::from_axis_angle(&Vector3::x_axis(), 34f64.to_radians());
    let file = as_file(&truth, &tilt, UpAxis::NegY, 0.0, 1);
    let mut scan = file.clone();
    let (report, _) = auto().apply(&mut scan).unwrap();
    let d = report.auto_up.clone().unwrap();
    assert_eq!(d.chosen.up_axis, UpAxis::NegY);
    assert!(
        (d.chosen.tilt_deg - 34.0).abs() < 0.05,
        "{}",
        d.chosen.tilt_deg
    );
    let text = report.to_string();
    eprintln!("{text}");
    assert!(
        text.contains("read as up axis -y and removed a tilt of 34.00°")
            && text.contains("moved from")
            && text.contains("runner-up: plane facing"),
        "{text}"
    );
    // The keys it prints as equivalent place the scan the same way, without `auto`.
    let [roll, pitch, yaw] = d.chosen.rotate_deg;
    let by_hand = Placement {
        up_axis: Some(UpAxis::NegY),
        transform: Some(Transform {
            rotate_deg: Some([roll, pitch, yaw]),
            ..Transform::default()
        }),
        floor: Floor::Auto,
    };
    let mut again = file.clone();
    by_hand.apply(&mut again).unwrap();
    let (floor_mean, _) = heights(&again, marks.floor);
    assert!(floor_mean.abs() < 0.005);
    for (a, b) in again.vertices.iter().zip(&scan.vertices) {
        assert!((vec3(a.position) - vec3(b.position)).norm() < 0.005);
    }
}

/// Parses the `[up_axis: …, transform: {rotate_deg: [a, b, c]}…]` of a listed candidate.
fn parse_pick(line: &str) -> Placement {
    let keys = &line[line.find("[up_axis: ").unwrap() + 1..];
    let up = keys
        .strip_prefix("up_axis: ")
        .and_then(|r| r.split([',', ']']).next())
        .and_then(UpAxis::from_name)
        .unwrap_or_else(|| panic!("no up_axis in {line}"));
    let rotate_deg = line.find("rotate_deg: [").map(|i| {
        let rest = &line[i + "rotate_deg: [".len()..];
        let v: Vec<f64> = rest[..rest.find(']').unwrap()]
            .split(',')
            .map(|x| x.trim().parse().unwrap())
            .collect();
        [v[0], v[1], v[2]]
    });
    Placement {
        up_axis: Some(up),
        transform: rotate_deg.map(|r| Transform {
            rotate_deg: Some(r),
            ..Transform::default()
        }),
        floor: Floor::Auto,
    }
}

#[test]
fn a_bare_closed_box_is_refused_with_candidates_that_each_level_it() {
    // Floor and ceiling alike, every wall facing its twin: nothing tells up.
    let (truth, _) = room(Room {
        size: [4.0, 5.0, 3.0],
        walls: true,
        ceiling: true,
        furnished: false,
    });
    let tilt = Rotation3::from_axis_angle(
        &Unit::new_normalize(Vector3::new(1.0, 2.0, 0.5)),
        27f64.to_radians(),
    );
    let file = as_file(&truth, &tilt, UpAxis::NegY, 0.0, 2);
    let e = auto().apply(&mut file.clone()).unwrap_err();
    assert!(matches!(e, SimError::Placement { .. }), "{e}");
    let text = e.to_string();
    eprintln!("{text}");
    assert!(
        text.contains("up_axis: auto") && text.contains("similar support"),
        "{text}"
    );
    let listed: Vec<&str> = text.lines().filter(|l| l.contains("[up_axis: ")).collect();
    assert_eq!(listed.len(), 6, "the six faces: {text}");
    // Each listed placement levels the box on one of its faces.
    let faces = [Vector3::x(), Vector3::y(), Vector3::z()].map(|a| tilt * a);
    for line in listed {
        let mut s = file.clone();
        let pick = parse_pick(line);
        let (report, _) = pick.apply(&mut s).unwrap();
        // File to world: the up axis, the transform's rotation, the levelling's.
        let turn = pick
            .transform
            .unwrap()
            .similarity()
            .unwrap()
            .isometry
            .rotation;
        let up = UnitQuaternion::from_rotation_matrix(&pick.up_axis.unwrap().rotation());
        let r = report.levelling.unwrap().transform.isometry.rotation * turn * up;
        let best = faces
            .iter()
            .map(|f| {
                let f = vec3(UpAxis::NegY.from_world([f.x as f32, f.y as f32, f.z as f32]));
                angle_deg(&(r * f), &Vector3::z()).min(angle_deg(&(r * -f), &Vector3::z()))
            })
            .fold(f64::INFINITY, f64::min);
        assert!(best < 0.5, "{line}: {best}° from a face");
    }
}

#[test]
fn a_scan_with_no_wall_is_refused_listing_its_floor() {
    let (truth, _) = room(Room {
        size: [5.0, 4.0, 2.5],
        walls: false,
        ceiling: false,
        furnished: true,
    });
    let tilt = Rotation3::from_axis_angle(&Vector3::y_axis(), 15f64.to_radians());
    let mut file = as_file(&truth, &tilt, UpAxis::Z, 0.0, 3);
    file.name = "floor_only.ply".into();
    let e = auto().apply(&mut file).unwrap_err().to_string();
    eprintln!("{e}");
    assert!(
        e.contains("floor_only.ply") && e.contains("no wall") && e.contains("1. plane facing"),
        "{e}"
    );
    assert!(e.contains("[up_axis: z, transform: {rotate_deg: ["), "{e}");
}

#[test]
fn a_procedural_house_tilted_50_degrees_navigates_like_the_house_with_up_axis_auto() {
    let spec = SceneSpec {
        max_rooms: Some(3),
        max_area: Some(40.0),
        ..SceneSpec::new("house:9")
    };
    let mut config = spec.house_config().unwrap();
    config.texture_size = 16;
    let house = crate::house::generate(9, &config).unwrap();
    let sim_config = SimConfig::with_resolution(16, 16);
    let area = Simulator::new(house.scene.clone(), sim_config.clone())
        .unwrap()
        .navigation()
        .map()
        .area();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(50);
    let tilt = Rotation3::from_axis_angle(&random_axis(&mut rng), 50f64.to_radians());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("house_scan.obj");
    write_obj(&path, &as_file(&house.scene, &tilt, UpAxis::NegY, 0.0, 0));
    let auto_spec = SceneSpec {
        placement: auto(),
        ..SceneSpec::new(path.to_str().unwrap())
    };
    let loaded = auto_spec.load().unwrap();
    eprintln!("{}", loaded.placement.as_ref().unwrap());
    let sim = auto_spec.simulator(sim_config).unwrap();
    let levelled = sim.navigation().map().area();
    eprintln!("navigable: house {area:.2} m², levelled scan {levelled:.2} m²");
    assert_eq!(sim.navigation().floor_z(), 0.0);
    assert!(
        (levelled - area).abs() < 0.03 * area,
        "levelled {levelled} m² against {area} m²"
    );
}

#[test]
fn the_furnished_house_with_up_axis_auto_places_as_with_its_known_up_axis() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/scenes/aws_small_house.glb");
    if !path.is_file() {
        eprintln!(
            "skipping: {} is absent (the furnished house test needs it)",
            path.display()
        );
        return;
    }
    let known = load_scene(&path, &LoadOptions::default()).unwrap().scene;
    let loaded = load_scene(&path, &LoadOptions { placement: auto() }).unwrap();
    let report = loaded.placement.unwrap();
    eprintln!("{report}");
    let d = report.auto_up.unwrap();
    assert_eq!(d.chosen.up_axis, UpAxis::Y, "glTF's own up axis");
    assert!(d.chosen.tilt_deg < 0.05, "tilt {}°", d.chosen.tilt_deg);
    let l = report.levelling.unwrap();
    assert!(l.height.abs() < 0.005, "floor moved from {} m", l.height);
    let mut worst = 0.0f64;
    for (a, b) in loaded.scene.vertices.iter().zip(&known.vertices) {
        worst = worst.max((vec3(a.position) - vec3(b.position)).norm());
    }
    assert!(worst < 0.01, "a vertex is {worst} m from its known place");
}
