use crate::SimError;
use crate::load::{LoadOptions, UpAxis, load_scene};
use crate::render::{DepthRange, Renderer};
use crate::scene::Scene;
use crate::simulator::{SimConfig, Simulator};
use activemap_geometry::{Intrinsics, Isometry3, Point3, Vector3};
use std::path::{Path, PathBuf};

fn data_dir() -> Option<PathBuf> {
    let d = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
    if d.is_dir() {
        Some(d)
    } else {
        eprintln!("skipping: test data folder {} is absent", d.display());
        None
    }
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn err_of(path: &Path) -> SimError {
    load_scene(path, &LoadOptions::default()).unwrap_err()
}

#[test]
fn simple_room_glb_loads_and_renders() {
    let Some(data) = data_dir() else { return };
    let path = data.join("scenes/simple_room.glb");
    // This habitat-sim test asset is z-up despite glTF's y-up convention: its node transforms
    // stand the table legs along file z. Read as y-up, the floor plate would stand vertical.
    let as_y_up = load_scene(&path, &LoadOptions::default()).unwrap().scene;
    let e = as_y_up.bounds().unwrap();
    assert!(e.max.z - e.min.z > 10.0, "default glTF y-up reading");
    let loaded = load_scene(&path, &LoadOptions::up_axis(UpAxis::Z)).unwrap();
    let scene = loaded.scene;
    // 7 box meshes of 12 triangles each.
    assert_eq!(scene.triangles.len(), 84);
    let b = scene.bounds().unwrap();
    // The floor plate (2 × 5.26 by 2 × 5.42 m) is horizontal; the table stands on it.
    let ext = b.max - b.min;
    assert!(
        ext.x > 10.0 && ext.y > 10.0 && ext.z < 3.0,
        "extent {ext:?}"
    );
    let mut sim = Simulator::new(scene, SimConfig::with_resolution(120, 90)).unwrap();
    assert!(
        sim.navigation().map().area() > 50.0,
        "navigable {}",
        sim.navigation().map().area()
    );
    let frame = sim.render();
    let valid = frame.depth.iter().filter(|d| **d > 0.0).count();
    assert!(
        valid > frame.depth.len() / 4,
        "only {valid} pixels see the room"
    );
    // The file's one material is grey 0.8 (unlit: 204); primitives without a material get
    // glTF's default material, white (255). Nothing else may appear.
    for (i, d) in frame.depth.iter().enumerate() {
        if *d > 0.0 {
            let c = &frame.rgb[3 * i..3 * i + 3];
            assert!(
                c == [204, 204, 204] || c == [255, 255, 255],
                "pixel {i}: {c:?}"
            );
        }
    }
    // The table (top at glTF y ≈ 1.13 → world z) seen from above: a camera looking straight
    // down from 5 m reads the tabletop closer than the floor.
    let down = Isometry3::face_towards(
        &Point3::new(0.25, -0.25, 6.0),
        &Point3::new(0.25, -0.25, 0.0),
        &Vector3::y(),
    );
    // face_towards gives +z towards the target: an optical frame looking down.
    let k = Intrinsics::from_hfov(64, 64, 0.3);
    let f = Renderer::new().render(sim.scene(), &k, &down, DepthRange::default());
    let centre = f.depth_at(32, 32) as f64;
    let floor = sim.navigation().floor_z();
    assert!(
        centre < 6.0 - floor - 0.5,
        "tabletop depth {centre}, floor at {floor}"
    );
}

#[test]
fn missing_and_unknown_files_are_clear_errors() {
    let err = err_of(Path::new("/nonexistent/room.glb"));
    assert!(
        matches!(err, SimError::Io { .. }) && err.to_string().contains("/nonexistent/room.glb"),
        "{err}"
    );
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "scene.fbx", b"whatever");
    let err = err_of(&p);
    assert!(
        matches!(err, SimError::UnsupportedFormat { .. }) && err.to_string().contains("scene.fbx"),
        "{err}"
    );
}

#[test]
fn malformed_gltf_files_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    for (name, bytes) in [
        ("garbage.glb", b"this is not a glb file at all".to_vec()),
        ("truncated.glb", {
            let mut v = b"glTF".to_vec();
            v.extend_from_slice(&2u32.to_le_bytes());
            v.extend_from_slice(&1000u32.to_le_bytes());
            v.extend_from_slice(&[1, 2, 3]);
            v
        }),
        ("bad.gltf", b"{\"asset\": {\"version\": \"2.0\"}, \"meshes\": [{\"primitives\": [{\"attributes\": {\"POSITION\": 5}}]}]}".to_vec()),
        ("nobin.gltf", br#"{"asset":{"version":"2.0"},"buffers":[{"uri":"missing.bin","byteLength":36}],
            "bufferViews":[{"buffer":0,"byteLength":36}],
            "accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}],
            "meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}]}"#.to_vec()),
    ] {
        let p = write(dir.path(), name, &bytes);
        let err = err_of(&p);
        assert!(matches!(err, SimError::Malformed { format: "glTF", .. }), "{name}: {err}");
        assert!(err.to_string().contains(name), "{name}: {err}");
    }
}

/// A one-triangle glTF with an external buffer and a texture whose image file is missing.
fn gltf_with_missing_texture(dir: &Path) -> PathBuf {
    let mut bin = Vec::new();
    for v in [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        v.iter()
            .for_each(|c| bin.extend_from_slice(&c.to_le_bytes()));
    }
    for v in [[0.0f32, 0.0], [1.0, 0.0], [0.0, 1.0]] {
        v.iter()
            .for_each(|c| bin.extend_from_slice(&c.to_le_bytes()));
    }
    write(dir, "tri.bin", &bin);
    let json = r#"{"asset":{"version":"2.0"},"buffers":[{"uri":"tri.bin","byteLength":60}],
        "bufferViews":[{"buffer":0,"byteLength":36},{"buffer":0,"byteOffset":36,"byteLength":24}],
        "accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]},
                     {"bufferView":1,"componentType":5126,"count":3,"type":"VEC2"}],
        "images":[{"uri":"missing.png"}],"textures":[{"source":0}],
        "materials":[{"pbrMetallicRoughness":{"baseColorFactor":[0.2,0.4,0.6,1],"baseColorTexture":{"index":0}}}],
        "meshes":[{"primitives":[{"attributes":{"POSITION":0,"TEXCOORD_0":1},"material":0}]}],
        "nodes":[{"mesh":0,"translation":[0,0,-2]}],"scenes":[{"nodes":[0]}],"scene":0}"#;
    write(dir, "tri.gltf", json.as_bytes())
}

#[test]
fn gltf_missing_texture_warns_and_keeps_the_flat_colour() {
    let dir = tempfile::tempdir().unwrap();
    let p = gltf_with_missing_texture(dir.path());
    let loaded = load_scene(&p, &LoadOptions::default()).unwrap();
    assert_eq!(loaded.warnings.len(), 1);
    assert!(
        loaded.warnings[0].to_string().contains("missing.png"),
        "{}",
        loaded.warnings[0]
    );
    let s = loaded.scene;
    assert_eq!(s.materials[0].texture, None);
    assert_eq!(s.materials[0].base_color, [0.2, 0.4, 0.6]);
    // Node translation (0, 0, −2) in glTF → world (0, 2, 0); glTF (0, 1, 0) → world z = 1.
    let pos: Vec<[f32; 3]> = s.vertices.iter().map(|v| v.position).collect();
    assert_eq!(pos, vec![[0.0, 2.0, 0.0], [1.0, 2.0, 0.0], [0.0, 2.0, 1.0]]);
}

/// Writes an OBJ quad at x = 2 (y-up file: facing the world camera looking along +x), its MTL
/// and a 2×2 PNG texture.
fn obj_quad(dir: &Path, texture: Option<&str>) -> PathBuf {
    // 4×4 texels in four constant 2×2 quadrants, so bilinear sampling inside a quadrant is exact.
    let img = image::RgbImage::from_fn(4, 4, |x, y| {
        image::Rgb([
            if x < 2 { 250 } else { 10 },
            if y < 2 { 250 } else { 10 },
            90,
        ])
    });
    img.save(dir.join("tex.png")).unwrap();
    let mtl = format!(
        "newmtl paint\nKd 0.5 0.5 0.5\n{}\n",
        texture.map(|t| format!("map_Kd {t}")).unwrap_or_default()
    );
    write(dir, "quad.mtl", mtl.as_bytes());
    // File coordinates are y-up: world (x, y, z) = (x_f, −z_f, y_f). The quad spans world
    // y ∈ [−1, 1], z ∈ [0, 2] at x = 2, i.e. file z_f ∈ [−1, 1], y_f ∈ [0, 2].
    // OBJ v is up: vt (0, 1) is the image's top-left.
    let obj = "mtllib quad.mtl\n\
        v 2 2 -1\nv 2 2 1\nv 2 0 1\nv 2 0 -1\n\
        vt 0 1\nvt 1 1\nvt 1 0\nvt 0 0\n\
        usemtl paint\nf 1/1 2/2 3/3 4/4\n";
    write(dir, "quad.obj", obj.as_bytes())
}

#[test]
fn obj_with_png_texture_loads_in_the_world_frame_and_renders_the_texture() {
    let dir = tempfile::tempdir().unwrap();
    let p = obj_quad(dir.path(), Some("tex.png"));
    let loaded = load_scene(&p, &LoadOptions::default()).unwrap();
    assert!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
    let s = loaded.scene;
    assert_eq!(s.triangles.len(), 2);
    assert_eq!(s.textures.len(), 1);
    assert_eq!(s.vertices[0].position, [2.0, 1.0, 2.0]);
    // Camera at the origin, 1 m up, looking along +x: world +y (file −z) is image left.
    let pose = activemap_geometry::camera_pose_from_planar(
        &activemap_geometry::PlanarPose::new(0.0, 0.0, 0.0),
        0.0,
        1.0,
    );
    let k = Intrinsics::from_hfov(40, 40, std::f64::consts::FRAC_PI_2);
    let f = Renderer::new().render(&s, &k, &pose, DepthRange::default());
    // The quad spans pixel coordinates 9.5 … 29.5 both ways (fx = 20, cx = 19.5, 2 m away).
    // Pixel 13 maps to texel coordinate 0.175·4 − 0.5 = 0.2 (top-left quadrant), pixel 26 to
    // 2.8 (bottom-right). Top-left quadrant (250, 250, 90) × Kd 0.5.
    let tl = f.rgb_at(13, 13);
    let br = f.rgb_at(26, 26);
    assert_eq!(tl, [125, 125, 45], "top-left {tl:?}");
    assert_eq!(br, [5, 5, 45], "bottom-right {br:?}");
    assert!((f.depth_at(20, 20) - 2.0).abs() < 1e-5);
}

#[test]
fn obj_problems_error_or_warn_by_severity() {
    let dir = tempfile::tempdir().unwrap();
    // Missing texture: loads, warns, flat colour.
    let p = obj_quad(dir.path(), Some("nowhere.jpg"));
    let loaded = load_scene(&p, &LoadOptions::default()).unwrap();
    assert!(
        loaded
            .warnings
            .iter()
            .any(|w| w.to_string().contains("nowhere.jpg")),
        "{:?}",
        loaded.warnings
    );
    assert_eq!(loaded.scene.materials[0].texture, None);
    // Missing material library: loads, warns, grey.
    let p = write(
        dir.path(),
        "nomtl.obj",
        b"mtllib absent.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    );
    let loaded = load_scene(&p, &LoadOptions::default()).unwrap();
    assert_eq!(loaded.warnings.len(), 1, "{:?}", loaded.warnings);
    // Face index out of range: error naming the file.
    let p = write(
        dir.path(),
        "badface.obj",
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
    );
    let err = err_of(&p);
    assert!(
        matches!(err, SimError::Malformed { format: "OBJ", .. })
            && err.to_string().contains("badface.obj"),
        "{err}"
    );
    // Unparsable vertex.
    let p = write(
        dir.path(),
        "badvertex.obj",
        b"v 0 zero 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    );
    let err = err_of(&p);
    assert!(err.to_string().contains("badvertex.obj"), "{err}");
    // No faces at all.
    let p = write(dir.path(), "empty.obj", b"v 0 0 0\n");
    assert!(matches!(err_of(&p), SimError::EmptyScene(_)));
}

#[test]
fn ply_with_vertex_colours_loads_z_up() {
    let dir = tempfile::tempdir().unwrap();
    let ply = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
        property uchar red\nproperty uchar green\nproperty uchar blue\nelement face 1\n\
        property list uchar int vertex_indices\nend_header\n\
        0 0 0 255 0 0\n1 0 0 0 255 0\n1 1 0 0 0 255\n0 1 0 255 255 255\n4 0 1 2 3\n";
    let p = write(dir.path(), "quad.ply", ply.as_bytes());
    let s = load_scene(&p, &LoadOptions::default()).unwrap().scene;
    assert_eq!(s.triangles.len(), 2);
    assert_eq!(s.vertices[2].position, [1.0, 1.0, 0.0]);
    assert_eq!(s.vertices[1].color, [0.0, 1.0, 0.0]);
    // Same file read as y-up: (1, 1, 0) → (1, 0, 1).
    let y = load_scene(&p, &LoadOptions::up_axis(UpAxis::from_name("Y").unwrap()))
        .unwrap()
        .scene;
    assert_eq!(y.vertices[2].position, [1.0, 0.0, 1.0]);

    for (name, text) in [
        ("garbage.ply", "not a ply\n".to_string()),
        ("badindex.ply", ply.replace("4 0 1 2 3", "3 0 1 7")),
        ("noface.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n".to_string()),
        ("truncated.ply", ply[..ply.len() - 12].to_string()),
    ] {
        let p = write(dir.path(), name, text.as_bytes());
        let err = err_of(&p);
        assert!(matches!(err, SimError::Malformed { format: "PLY", .. }), "{name}: {err}");
        assert!(err.to_string().contains(name), "{name}: {err}");
    }
}

#[test]
fn scene_load_convenience_reads_default_options() {
    let dir = tempfile::tempdir().unwrap();
    let p = obj_quad(dir.path(), None);
    let s = Scene::load(&p).unwrap();
    assert_eq!(s.materials[0].base_color, [0.5, 0.5, 0.5]);
}

/// The furnished AWS RoboMaker Small House (`../shared/data/scenes/aws_small_house.glb`, see the
/// data README: 19 × 11.4 m, 3.0 m walls, floor at glTF y = 0, 65 embedded textures) loads with
/// its textures, level, with a navigable floor of a furnished house's size, and a derived start
/// clear of the furniture that sees the room.
#[test]
fn the_furnished_house_loads_with_its_textures_and_a_sane_floor() {
    let Some(data) = data_dir() else { return };
    let path = data.join("scenes/aws_small_house.glb");
    if !path.is_file() {
        eprintln!("skipping: {} is absent", path.display());
        return;
    }
    let loaded = load_scene(&path, &LoadOptions::default()).unwrap();
    let scene = loaded.scene;
    assert_eq!(scene.textures.len(), 65, "embedded textures");
    assert_eq!(scene.triangles.len(), 147_872);
    let b = scene.bounds().unwrap();
    let ext = b.max - b.min;
    assert!(
        (ext.x - 19.0).abs() < 0.1 && (ext.y - 11.4).abs() < 0.1 && (ext.z - 3.0).abs() < 0.05,
        "extent {ext:?}"
    );
    let mut sim = Simulator::new(scene, SimConfig::with_resolution(64, 64)).unwrap();
    let nav = sim.navigation();
    // The floor at z = 0 (carpets lie 1–3 mm above it).
    assert!(nav.floor_z().abs() < 0.005, "floor at {}", nav.floor_z());
    // The house is 216 m² inside its walls; furniture and the robot's radius take a share.
    let area = nav.map().area();
    assert!((100.0..200.0).contains(&area), "navigable {area} m²");
    let start = sim.true_planar_pose();
    let map = nav.map();
    let (i, j) = map.frame.cell_of(start.x, start.y).unwrap();
    let clearance = map.clearance()[j * map.frame.width + i];
    assert!(
        clearance >= crate::navigation::START_CLEARANCE_M,
        "start {start:?} has {clearance} m of free floor"
    );
    let frame = sim.render();
    let valid = frame.depth.iter().filter(|d| **d > 0.0).count();
    assert!(
        valid > frame.depth.len() / 2,
        "the start sees {valid} pixels"
    );
}
