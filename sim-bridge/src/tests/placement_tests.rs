//! Scene placement: the six up axes, the transform (parts and matrix), `floor: auto` on
//! tilted scenes, and the refusals, each against hand-computed or generated truth.

use super::fixtures::{add_box_faces, flat, push_quad};
use crate::house::{self, House};
use crate::load::{LoadOptions, load_scene};
use crate::scene::Scene;
use crate::simulator::{SimConfig, Simulator};
use crate::{Floor, Placement, SceneSpec, SimError, Transform, UpAxis};
use nalgebra::{Rotation3, Unit, Vector3};
use rand::{Rng, SeedableRng};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn vec3(p: [f32; 3]) -> Vector3<f64> {
    Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)
}

/// Writes the triangles of `scene` as a Wavefront OBJ (positions only, one `v` per vertex in
/// order), each position mapped into the file's frame by `to_file` first.
fn write_obj(path: &Path, scene: &Scene, to_file: impl Fn(Vector3<f64>) -> Vector3<f64>) {
    let mut text = String::new();
    for v in &scene.vertices {
        let p = to_file(vec3(v.position));
        writeln!(text, "v {:.7} {:.7} {:.7}", p.x, p.y, p.z).unwrap();
    }
    for t in &scene.triangles {
        let [a, b, c] = t.vertices.map(|i| i + 1);
        writeln!(text, "f {a} {b} {c}").unwrap();
    }
    std::fs::write(path, text).unwrap();
}

fn placement(up: Option<UpAxis>, transform: Option<Transform>, floor: Floor) -> LoadOptions {
    LoadOptions {
        placement: Placement {
            up_axis: up,
            transform,
            floor,
        },
    }
}

fn assert_close(got: [f32; 3], want: [f64; 3], tol: f64, what: &str) {
    let d = (vec3(got) - Vector3::from(want)).norm();
    assert!(d <= tol, "{what}: got {got:?}, want {want:?}");
}

/// The angle between two vectors, degrees.
fn angle_deg(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    (a.dot(b) / (a.norm() * b.norm()))
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

#[test]
fn every_up_axis_turns_the_files_up_to_world_z_by_a_proper_rotation() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("marks.obj");
    // The three unit axes, two asymmetric points and the origin, in two triangles.
    let obj = "v 1 0 0\nv 0 1 0\nv 0 0 1\nv 1 2 3\nv -4 5 -6\nv 0 0 0\nf 1 2 3\nf 4 5 6\n";
    std::fs::write(&path, obj).unwrap();
    // Hand-computed images of (1, 2, 3) and (−4, 5, −6) and the file's up direction.
    type Row = (&'static str, [f64; 3], [f64; 3], [f64; 3]);
    let table: [Row; 6] = [
        ("x", [-3.0, 2.0, 1.0], [6.0, 5.0, -4.0], [1.0, 0.0, 0.0]),
        ("-x", [3.0, 2.0, -1.0], [-6.0, 5.0, 4.0], [-1.0, 0.0, 0.0]),
        ("y", [1.0, -3.0, 2.0], [-4.0, 6.0, 5.0], [0.0, 1.0, 0.0]),
        ("-y", [1.0, 3.0, -2.0], [-4.0, -6.0, -5.0], [0.0, -1.0, 0.0]),
        ("z", [1.0, 2.0, 3.0], [-4.0, 5.0, -6.0], [0.0, 0.0, 1.0]),
        ("-z", [1.0, -2.0, -3.0], [-4.0, -5.0, 6.0], [0.0, 0.0, -1.0]),
    ];
    for (name, p1, p2, up_dir) in table {
        let up = UpAxis::from_name(name).unwrap();
        assert_eq!(UpAxis::from_name(up.name()), Some(up), "{name} round-trips");
        let s = load_scene(&path, &placement(Some(up), None, Floor::None))
            .unwrap()
            .scene;
        let v: Vec<Vector3<f64>> = s.vertices.iter().map(|v| vec3(v.position)).collect();
        assert_eq!(v.len(), 6, "{name}");
        assert_close(s.vertices[3].position, p1, 0.0, name);
        assert_close(s.vertices[4].position, p2, 0.0, name);
        // The file's up direction is world +z.
        let up_image = up.rotation() * Vector3::from(up_dir);
        assert_eq!(up_image, Vector3::z(), "{name}");
        // The images of the file axes form a rotation: orthonormal with determinant +1.
        let m = nalgebra::Matrix3::from_columns(&[v[0], v[1], v[2]]);
        assert_eq!(m.transpose() * m, nalgebra::Matrix3::identity(), "{name}");
        assert_eq!(m.determinant(), 1.0, "{name}");
        assert_eq!(m, *up.rotation().matrix(), "{name}");
        // A proper rotation keeps the winding: the world normal is the rotated file normal.
        let n_file = Vector3::new(1.0, 1.0, 1.0); // (e_y − e_x) × (e_z − e_x)
        assert_eq!(s.scaled_normal(&s.triangles[0]), m * n_file, "{name}");
        // from_world inverts to_world.
        assert_eq!(up.from_world(up.to_world([1.0, 2.0, 3.0])), [1.0, 2.0, 3.0]);
    }
    // Spellings: case, `+`, `-up`; nonsense is refused.
    for (name, up) in [
        ("+X", UpAxis::X),
        (" -Y ", UpAxis::NegY),
        ("y-up", UpAxis::Y),
        ("Z-UP", UpAxis::Z),
        ("-z", UpAxis::NegZ),
        ("-x-up", UpAxis::NegX),
    ] {
        assert_eq!(UpAxis::from_name(name), Some(up), "{name}");
    }
    for bad in ["w", "xy", "--y", "+-z", "", "up"] {
        assert_eq!(UpAxis::from_name(bad), None, "{bad:?}");
    }
}

#[test]
fn a_transform_scales_rotates_and_translates_after_the_up_axis() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cm.obj");
    // A y-up file in centimetres.
    std::fs::write(&path, "v 100 200 300\nv 0 0 0\nv 0 100 0\nf 1 2 3\n").unwrap();
    let parts = Transform {
        scale: Some(0.01),
        rotate_deg: Some([0.0, 0.0, 90.0]),
        translate: Some([1.0, 2.0, 3.0]),
        matrix: None,
    };
    // By hand: y-up (100, 200, 300) → (100, −300, 200); × 0.01 → (1, −3, 2); yaw 90°
    // (x, y) → (−y, x) → (3, 1, 2); + (1, 2, 3) → (4, 3, 5). The origin lands on t; file
    // (0, 100, 0) is 1 m up: (1, 2, 4).
    let want = [[4.0, 3.0, 5.0], [1.0, 2.0, 3.0], [1.0, 2.0, 4.0]];
    let matrix = Transform {
        matrix: Some([
            0.0, -0.01, 0.0, 1.0, //
            0.01, 0.0, 0.0, 2.0, //
            0.0, 0.0, 0.01, 3.0, //
            0.0, 0.0, 0.0, 1.0,
        ]),
        ..Transform::default()
    };
    let plain = load_scene(&path, &LoadOptions::default()).unwrap().scene;
    for t in [parts, matrix] {
        let loaded = load_scene(&path, &placement(None, Some(t), Floor::None)).unwrap();
        let s = loaded.scene;
        for (v, w) in s.vertices.iter().zip(want) {
            assert_close(v.position, w, 1e-6, &t.to_string());
        }
        // Normals turn with the scene and scale by s² (area): n' = s²·R·n.
        let rz = Rotation3::from_axis_angle(&Vector3::z_axis(), std::f64::consts::FRAC_PI_2);
        let n0 = plain.scaled_normal(&plain.triangles[0]);
        let n1 = s.scaled_normal(&s.triangles[0]);
        assert!(
            (n1 - 1e-4 * (rz * n0)).norm() < 1e-6 * n0.norm(),
            "{n1} vs {n0}"
        );
        let report = loaded.placement.expect("a placement key was set");
        assert_eq!((report.up_axis, report.floor_z), (UpAxis::Y, None));
        assert!(
            report.to_string().contains("up axis y; transform"),
            "{report}"
        );
    }
    // Euler order R = Rz(yaw)·Ry(pitch)·Rx(roll), against quarter turns composed by hand:
    // Rx(90°) takes +y to +z, Ry(90°) takes +z to +x, Rz(90°) takes +x to +y; so [90, 90, 90]
    // takes +y → +z → +x → +y (the opposite order would give −y).
    for (rotate_deg, want) in [
        ([90.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        ([0.0, 90.0, 0.0], [0.0, 1.0, 0.0]),
        ([90.0, 90.0, 0.0], [1.0, 0.0, 0.0]),
        ([90.0, 90.0, 90.0], [0.0, 1.0, 0.0]),
    ] {
        let mut s = Scene::default();
        let m = flat(&mut s, [1.0; 3]);
        push_quad(
            &mut s,
            [
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0],
            ],
            [[0.0; 2]; 4],
            m,
        );
        let p = Placement {
            transform: Some(Transform {
                rotate_deg: Some(rotate_deg),
                ..Transform::default()
            }),
            ..Placement::default()
        };
        p.apply(&mut s).unwrap();
        assert_close(
            s.vertices[0].position,
            want,
            1e-6,
            &format!("{rotate_deg:?}"),
        );
    }
}

#[test]
fn a_placement_carries_the_scenes_own_floor_and_start_or_drops_them_with_a_reason() {
    let house = small_house(4);
    // Yaw 90° and a lift: the floor height and start pose follow exactly.
    let mut s = house.scene.clone();
    let yaw = Placement {
        transform: Some(Transform {
            rotate_deg: Some([0.0, 0.0, 90.0]),
            translate: Some([1.0, 2.0, 0.5]),
            ..Transform::default()
        }),
        ..Placement::default()
    };
    let (report, warnings) = yaw.apply(&mut s).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(s.floor_z, Some(0.5));
    assert_eq!(report.floor_z, Some(0.5));
    let (st, moved) = (house.start, s.start.unwrap());
    assert!((moved.x - (1.0 - st.y)).abs() < 1e-6 && (moved.y - (2.0 + st.x)).abs() < 1e-6);
    // The heading turned by the yaw, 90°.
    let turn = moved.yaw - st.yaw - std::f64::consts::FRAC_PI_2;
    assert!(
        turn.sin().abs() < 1e-9 && turn.cos() > 0.0,
        "yaw {}",
        moved.yaw
    );
    // The simulator of the moved house starts there, on the moved floor.
    let sim = Simulator::new(s, SimConfig::with_resolution(8, 8)).unwrap();
    assert_eq!(sim.true_planar_pose(), moved);
    assert_eq!(sim.navigation().floor_z(), 0.5);
    // A roll of 10° tilts the floor: both are dropped, each with a warning.
    let mut s = house.scene.clone();
    let roll = Placement {
        transform: Some(Transform {
            rotate_deg: Some([10.0, 0.0, 0.0]),
            ..Transform::default()
        }),
        ..Placement::default()
    };
    let (_, warnings) = roll.apply(&mut s).unwrap();
    assert_eq!((s.floor_z, s.start), (None, None));
    assert_eq!(warnings.len(), 2, "{warnings:?}");
    assert!(
        warnings
            .iter()
            .all(|w| w.message.contains("tilts the floor"))
    );
}

#[test]
fn matrices_that_are_not_a_rotation_times_a_uniform_scale_are_refused() {
    let parse = |v: serde_json::Value| serde_json::from_value::<Placement>(v);
    let m = |rows: [[f64; 4]; 4]| serde_json::json!({ "transform": { "matrix": rows.concat() } });
    let id = [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    let with = |r: usize, c: usize, v: f64| {
        let mut a = id;
        a[r][c] = v;
        a
    };
    for (what, rows, needle) in [
        ("shear", with(0, 1, 0.1), "shear or a non-uniform scale"),
        (
            "non-uniform scale",
            with(2, 2, 2.0),
            "shear or a non-uniform scale",
        ),
        ("reflection", with(2, 2, -1.0), "reflection"),
        ("collapse", with(2, 2, 0.0), "collapses"),
        (
            "projective row",
            with(3, 2, 1.0),
            "last row must be [0, 0, 0, 1]",
        ),
    ] {
        let e = parse(m(rows)).unwrap_err().to_string();
        assert!(e.contains(needle), "{what}: {e}");
    }
    let e = parse(serde_json::json!({ "transform": { "matrix": [1, 0, 0] } }))
        .unwrap_err()
        .to_string();
    assert!(e.contains("16"), "{e}");
    let e = parse(serde_json::json!({ "transform": { "matrix": id.concat(), "scale": 2 } }))
        .unwrap_err()
        .to_string();
    assert!(e.contains("not both"), "{e}");
    let e = parse(serde_json::json!({ "transform": { "scale": -1 } }))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("transform.scale must be a positive number"),
        "{e}"
    );
    let e = parse(serde_json::json!({ "transform": { "rotate": [0, 0, 1] } }))
        .unwrap_err()
        .to_string();
    assert!(e.contains("rotate"), "{e}");
    // Accepted: 2 × a 30° yaw printed with 4 decimals, plus a translation.
    let (c, s) = (1.7321, 1.0);
    let ok = parse(m([
        [c, -s, 0.0, 0.5],
        [s, c, 0.0, 0.0],
        [0.0, 0.0, 2.0, -1.0],
        [0.0, 0.0, 0.0, 1.0],
    ]))
    .unwrap();
    let sim = ok.transform.unwrap().similarity().unwrap();
    assert!((sim.scaling() - 2.0).abs() < 1e-4);
    // A transform built in code (no serde check) is refused at load time, naming the file.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tri.obj");
    std::fs::write(&path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let sheared = Transform {
        matrix: Some(with(0, 1, 0.1).concat().try_into().unwrap()),
        ..Transform::default()
    };
    let e = load_scene(&path, &placement(None, Some(sheared), Floor::None)).unwrap_err();
    assert!(matches!(e, SimError::Placement { .. }), "{e}");
    let e = e.to_string();
    assert!(e.contains("tri.obj") && e.contains("not a rotation"), "{e}");
}

#[test]
fn placement_settings_read_and_write_as_the_config_spells_them() {
    let json = serde_json::json!({
        "up_axis": "-Y",
        "transform": { "scale": 0.01, "rotate_deg": [1, 2, 3], "translate": [0.5, 0, -1] },
        "floor": "auto"
    });
    let p: Placement = serde_json::from_value(json).unwrap();
    assert_eq!(p.up_axis, Some(UpAxis::NegY));
    assert_eq!(p.floor, Floor::Auto);
    assert_eq!(p.transform.unwrap().rotate_deg, Some([1.0, 2.0, 3.0]));
    let back = serde_json::to_value(p).unwrap();
    assert_eq!(back["up_axis"], "-y");
    assert_eq!(back["floor"], "auto");
    assert_eq!(serde_json::from_value::<Placement>(back).unwrap(), p);
    // Defaults are left out; a number is a known floor height.
    assert_eq!(
        serde_json::to_value(Placement::default()).unwrap(),
        serde_json::json!({})
    );
    let h: Placement = serde_json::from_value(serde_json::json!({ "floor": -1.5 })).unwrap();
    assert_eq!(h.floor, Floor::Height(-1.5));
    let h: Placement = serde_json::from_value(serde_json::json!({ "floor": 2 })).unwrap();
    assert_eq!(h.floor, Floor::Height(2.0));
    let none: Placement = serde_json::from_value(serde_json::json!({ "floor": "None" })).unwrap();
    assert_eq!(none.floor, Floor::None);
    for (bad, needle) in [
        (
            serde_json::json!({ "floor": "flat" }),
            "floor must be `none`, `auto`",
        ),
        (
            serde_json::json!({ "up_axis": "w" }),
            "up_axis must be x, -x, y, -y, z or -z",
        ),
        (serde_json::json!({ "tilt": 3 }), "tilt"),
    ] {
        let e = serde_json::from_value::<Placement>(bad)
            .unwrap_err()
            .to_string();
        assert!(e.contains(needle), "{e}");
    }
}

/// A two- or three-room house with small textures.
fn small_house(seed: u64) -> House {
    let spec = SceneSpec {
        max_rooms: Some(3),
        max_area: Some(40.0),
        ..SceneSpec::new(format!("house:{seed}"))
    };
    let mut config = spec.house_config().unwrap();
    config.texture_size = 16;
    house::generate(seed, &config).unwrap()
}

/// 6° about the horizontal axis at 35° from x: the known tilt of the test scans.
fn tilt() -> Rotation3<f64> {
    let a = 35f64.to_radians();
    Rotation3::from_axis_angle(
        &Unit::new_normalize(Vector3::new(a.cos(), a.sin(), 0.0)),
        6f64.to_radians(),
    )
}

#[test]
fn floor_auto_levels_a_tilted_y_down_house_and_puts_its_floor_at_zero() {
    let house = small_house(5);
    let truth = house.scene.clone();
    // The house as a y-down scan: tilted, its floor 1.2 m below a camera at the origin, in
    // camera axes (x right, y down, z forward).
    let offset = Vector3::new(0.4, -0.3, -1.2);
    let mut scan = truth.clone();
    (scan.floor_z, scan.start) = (None, None);
    for v in &mut scan.vertices {
        let w = tilt() * vec3(v.position) + offset;
        v.position = UpAxis::NegY.from_world([w.x as f32, w.y as f32, w.z as f32]);
    }
    let p = Placement {
        up_axis: Some(UpAxis::NegY),
        floor: Floor::Auto,
        ..Placement::default()
    };
    let (report, warnings) = p.apply(&mut scan).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    let l = report.levelling.expect("levelled");
    // Tilt recovered: what is left of the tilt after levelling, against the known rotation.
    let residual = angle_deg(
        &(l.transform.isometry.rotation * (tilt() * Vector3::z())),
        &Vector3::z(),
    );
    eprintln!(
        "house: tilt found {:.4}° (true 6°), residual {residual:.2e}°, axis {:?}, floor {:.1} m², rms {:.2e} m",
        l.tilt_deg, l.axis, l.area, l.rms
    );
    assert!(residual < 0.5, "residual tilt {residual}°");
    assert!((l.tilt_deg - 6.0).abs() < 0.5);
    // The removed rotation undoes the tilt: its axis is the tilt axis, reversed.
    assert!(angle_deg(&l.axis, &-(tilt().axis().unwrap().into_inner())) < 0.5);
    assert_eq!((scan.floor_z, report.floor_z), (Some(0.0), Some(0.0)));
    // Every vertex is back where the house had it, up to a horizontal shift (the levelling
    // turns about the origin): floor vertices at z = 0 within 1 cm, all others likewise.
    let shift = vec3(scan.vertices[0].position) - vec3(truth.vertices[0].position);
    assert!(shift.z.abs() < 0.01, "shift {shift}");
    let mut worst = 0.0f64;
    for (a, b) in scan.vertices.iter().zip(&truth.vertices) {
        let d = vec3(a.position) - vec3(b.position) - Vector3::new(shift.x, shift.y, 0.0);
        worst = worst.max(d.norm());
        if b.position[2] == 0.0 {
            assert!(
                a.position[2].abs() < 0.01,
                "floor vertex at z = {}",
                a.position[2]
            );
        }
    }
    assert!(worst < 0.01, "a vertex is {worst} m from the house");
    let text = report.to_string();
    assert!(
        text.contains("up axis -y") && text.contains("removed a tilt of 6.00°"),
        "{text}"
    );
}

/// A 6 m × 4 m room (walls, ceiling) with a bed, a table and a 15° ramp on its floor, every
/// face subdivided 3 times and every vertex moved by a seeded uniform ±6 mm: a rough scan.
/// Returns the scene and the floor's material.
fn noisy_room() -> (Scene, u32) {
    let mut s = Scene {
        name: "noisy room".into(),
        ..Scene::default()
    };
    let m: Vec<u32> = (0..6).map(|k| flat(&mut s, [0.2 * k as f32; 3])).collect();
    add_box_faces(&mut s, [0.0, 0.0, 0.0], [6.0, 4.0, 2.6], &m);
    let furniture = flat(&mut s, [0.5, 0.3, 0.1]);
    let f = [furniture; 6];
    add_box_faces(&mut s, [0.2, 0.2, 0.0], [2.2, 1.8, 0.5], &f); // bed
    add_box_faces(&mut s, [4.0, 2.5, 0.0], [5.2, 3.3, 0.75], &f); // table
    push_quad(
        &mut s,
        [
            [3.5, 0.3, 0.0],
            [5.5, 0.3, 0.0],
            [5.5, 1.8, 0.4],
            [3.5, 1.8, 0.4],
        ],
        [[0.0; 2]; 4],
        furniture,
    );
    let mut s = s.subdivided(3);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(16);
    for v in &mut s.vertices {
        for c in &mut v.position {
            *c += rng.random_range(-0.006f32..0.006);
        }
    }
    (s, m[4])
}

#[test]
fn floor_auto_levels_a_rough_scan_in_centimetres_with_clutter_on_the_floor() {
    let (room, floor_material) = noisy_room();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("scan_cm.obj");
    // x-up file in centimetres, tilted 6° and offset.
    let offset = Vector3::new(-2.0, 1.0, 0.8);
    write_obj(&path, &room, |p| {
        let w = 100.0 * (tilt() * p + offset);
        let f = UpAxis::X.from_world([w.x as f32, w.y as f32, w.z as f32]);
        vec3(f)
    });
    let options = placement(
        Some(UpAxis::X),
        Some(Transform {
            scale: Some(0.01),
            ..Transform::default()
        }),
        Floor::Auto,
    );
    let loaded = load_scene(&path, &options).unwrap();
    let report = loaded.placement.unwrap();
    let l = report.levelling.unwrap();
    let residual = angle_deg(
        &(l.transform.isometry.rotation * (tilt() * Vector3::z())),
        &Vector3::z(),
    );
    // The floor's mean height, and the height at each quarter of the room (which a residual
    // tilt would spread apart). The OBJ keeps the triangle order, hence the corners.
    let placed = &loaded.scene;
    assert_eq!(placed.triangles.len(), room.triangles.len());
    let mut quarters = [(0.0, 0usize); 4];
    let (mut sum, mut n) = (0.0, 0usize);
    for (t, u) in room.triangles.iter().zip(&placed.triangles) {
        if t.material != floor_material {
            continue;
        }
        for (o, p) in room.corners(t).iter().zip(placed.corners(u)) {
            let q = usize::from(o.x > 3.0) + 2 * usize::from(o.y > 2.0);
            quarters[q].0 += p.z;
            quarters[q].1 += 1;
            sum += p.z;
            n += 1;
        }
    }
    let mean = sum / n as f64;
    let spread = quarters
        .iter()
        .map(|(s, n)| s / *n as f64)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), z| {
            (lo.min(z), hi.max(z))
        });
    eprintln!(
        "rough scan: tilt found {:.4}° (true 6°), residual {residual:.4}°, floor mean z {:.2} mm, \
         quarter means {:.2}…{:.2} mm, plane on {:.1} m², rms {:.1} mm",
        l.tilt_deg,
        mean * 1e3,
        spread.0 * 1e3,
        spread.1 * 1e3,
        l.area,
        l.rms * 1e3
    );
    assert!(residual < 0.5, "residual tilt {residual}°");
    assert!(mean.abs() < 0.01, "floor at {mean} m");
    assert!(spread.1 - spread.0 < 0.01, "floor quarters {spread:?}");
    // The ramp (3.1 m²) and the furniture tops are not floor: the plane holds the floor's
    // 24 m² and the bed's and table's bottom faces lying on it (3.2 + 0.96 m²), no more.
    assert!(l.area > 27.5 && l.area < 28.5, "floor area {}", l.area);
    assert_eq!(placed.floor_z, Some(0.0));
}

#[test]
fn a_scene_without_a_floor_is_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    // Four walls, no floor.
    let mut walls = Scene::default();
    let m = flat(&mut walls, [1.0; 3]);
    let uv = [[0.0; 2]; 4];
    for q in [
        [
            [0.0, 0.0, 0.0],
            [4.0, 0.0, 0.0],
            [4.0, 0.0, 2.5],
            [0.0, 0.0, 2.5],
        ],
        [
            [4.0, 0.0, 0.0],
            [4.0, 3.0, 0.0],
            [4.0, 3.0, 2.5],
            [4.0, 0.0, 2.5],
        ],
        [
            [4.0, 3.0, 0.0],
            [0.0, 3.0, 0.0],
            [0.0, 3.0, 2.5],
            [4.0, 3.0, 2.5],
        ],
        [
            [0.0, 3.0, 0.0],
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 2.5],
            [0.0, 3.0, 2.5],
        ],
    ] {
        push_quad(&mut walls, q, uv, m);
    }
    // A 0.6 m × 0.6 m floor tile is not enough either.
    let mut tile = walls.clone();
    push_quad(
        &mut tile,
        [
            [1.0, 1.0, 0.0],
            [1.6, 1.0, 0.0],
            [1.6, 1.6, 0.0],
            [1.0, 1.6, 0.0],
        ],
        uv,
        m,
    );
    for (name, scene) in [("walls.obj", &walls), ("tile.obj", &tile)] {
        let path = dir.path().join(name);
        write_obj(&path, scene, |p| {
            vec3(UpAxis::Y.from_world([p.x as f32, p.y as f32, p.z as f32]))
        });
        let e = load_scene(&path, &placement(None, None, Floor::Auto)).unwrap_err();
        assert!(matches!(e, SimError::Placement { .. }), "{e}");
        let e = e.to_string();
        assert!(
            e.contains(name) && e.contains("found no floor") && e.contains("up_axis"),
            "{e}"
        );
        // Read as it is (no levelling) the walls still load.
        load_scene(&path, &LoadOptions::default()).unwrap();
    }
}

#[test]
fn a_tilted_y_down_obj_of_a_house_navigates_like_the_house_once_levelled() {
    let house = small_house(9);
    let config = SimConfig::with_resolution(16, 16);
    let truth = Simulator::new(house.scene.clone(), config.clone()).unwrap();
    let area = truth.navigation().map().area();
    let dir = tempfile::tempdir().unwrap();
    let path: PathBuf = dir.path().join("house_scan.obj");
    let offset = Vector3::new(0.3, 0.2, -1.1);
    write_obj(&path, &house.scene, |p| {
        let w = tilt() * p + offset;
        vec3(UpAxis::NegY.from_world([w.x as f32, w.y as f32, w.z as f32]))
    });
    let spec = SceneSpec {
        placement: Placement {
            up_axis: Some(UpAxis::NegY),
            floor: Floor::Auto,
            ..Placement::default()
        },
        ..SceneSpec::new(path.to_str().unwrap())
    };
    let sim = spec.simulator(config.clone()).unwrap();
    let levelled = sim.navigation().map().area();
    eprintln!("navigable: house {area:.2} m², levelled scan {levelled:.2} m²");
    assert_eq!(sim.navigation().floor_z(), 0.0);
    assert!(
        (levelled - area).abs() < 0.03 * area,
        "levelled {levelled} m² against {area} m²"
    );
    let start = sim.true_planar_pose();
    assert!(sim.navigation().is_navigable(start.x, start.y));
    // Without levelling, the 6° tilt leaves most of the floor out of reach (or none at all).
    let as_is = SceneSpec {
        placement: Placement {
            up_axis: Some(UpAxis::NegY),
            ..Placement::default()
        },
        ..spec.clone()
    };
    match as_is.simulator(config) {
        Ok(s) => {
            let a = s.navigation().map().area();
            assert!(a < 0.5 * area, "unlevelled {a} m² against {area} m²");
        }
        Err(e) => assert!(matches!(e, SimError::NoNavigableArea(_)), "{e}"),
    }
}
