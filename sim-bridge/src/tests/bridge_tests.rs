//! The Python bridge codecs (`sim-bridge/python/activemap_bridge.py`) produce exactly the
//! payloads the pipeline's schemas decode, and decode the actions the pipeline encodes.

use crate::simulator::{SimConfig, Simulator};
use activemap_schemas::{
    Action, ActionKind, EpisodeState, EpisodeStatus, RgbdFrameView, SmallMessage, TruePose,
};
use std::path::Path;
use std::process::Command;

fn python() -> Option<&'static str> {
    let ok = Command::new("python3")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        eprintln!("skipping: python3 is not available");
    }
    ok.then_some("python3")
}

fn run_python(code: &str, dir: &Path) -> String {
    let module = Path::new(env!("CARGO_MANIFEST_DIR")).join("python");
    let out = Command::new("python3")
        .arg("-c")
        .arg(code)
        .env("PYTHONPATH", &module)
        .env("PYTHONDONTWRITEBYTECODE", "1")
        .current_dir(dir)
        .output()
        .expect("python3 runs");
    assert!(
        out.status.success(),
        "python failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

#[test]
fn python_codecs_match_the_pipeline_schemas() {
    let Some(_) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    // A real rendered frame (odd size, so section padding matters).
    let scene = super::fixtures::box_room([-1.0, -2.0, 0.0], [3.0, 2.0, 2.5]);
    let mut sim = Simulator::new(scene, SimConfig::with_resolution(7, 5)).unwrap();
    let frame = sim.render();
    std::fs::write(dir.path().join("rgb.bin"), &frame.rgb).unwrap();
    let depth: Vec<u8> = frame.depth.iter().flat_map(|d| d.to_le_bytes()).collect();
    std::fs::write(dir.path().join("depth.bin"), &depth).unwrap();
    let k = frame.intrinsics;
    let code = format!(
        "import activemap_bridge as b\n\
         rgb = open('rgb.bin', 'rb').read(); depth = open('depth.bin', 'rb').read()\n\
         open('rgbd.bin', 'wb').write(b.encode_rgbd(41, 4.1, ({}, {}, {}, {}), 7, 5, rgb, depth))\n\
         open('pose.bin', 'wb').write(b.encode_true_pose(41, 4.1, (1.0, -2.0, 0.88), (0.5, -0.5, 0.5, -0.5)))\n\
         open('status.bin', 'wb').write(b.encode_episode_status(300, 2000, 'finished', 'stop: 完'))\n",
        k.fx, k.fy, k.cx, k.cy
    );
    run_python(&code, dir.path());

    let bytes = std::fs::read(dir.path().join("rgbd.bin")).unwrap();
    let view = RgbdFrameView::parse(&bytes).unwrap();
    assert_eq!(view.header.payload_len().unwrap(), bytes.len());
    assert_eq!((view.header.frame_id, view.header.stamp), (41, 4.1));
    assert_eq!((view.header.width, view.header.height), (7, 5));
    assert_eq!(
        [
            view.header.fx,
            view.header.fy,
            view.header.cx,
            view.header.cy
        ],
        [k.fx, k.fy, k.cx, k.cy]
    );
    assert_eq!(view.rgb, &frame.rgb[..]);
    assert_eq!(&view.depth()[..], &frame.depth[..]);

    let pose = TruePose::decode(&std::fs::read(dir.path().join("pose.bin")).unwrap()).unwrap();
    assert_eq!((pose.frame_id, pose.stamp), (41, 4.1));
    assert_eq!(pose.t_world_camera.translation, [1.0, -2.0, 0.88]);
    assert_eq!(pose.t_world_camera.rotation_xyzw, [0.5, -0.5, 0.5, -0.5]);

    let status =
        EpisodeStatus::decode(&std::fs::read(dir.path().join("status.bin")).unwrap()).unwrap();
    assert_eq!(
        (status.step, status.max_steps, status.state),
        (300, 2000, EpisodeState::Finished)
    );
    assert_eq!(status.message, "stop: 完");

    // And the other way: actions encoded by the pipeline decode in Python.
    for (step, kind, name) in [
        (0u64, ActionKind::Forward, "forward"),
        (127, ActionKind::TurnLeft, "turn_left"),
        (128, ActionKind::TurnRight, "turn_right"),
        (1_000_000, ActionKind::Stop, "stop"),
    ] {
        let bytes = Action { step, action: kind }.encode();
        std::fs::write(dir.path().join("action.bin"), &bytes).unwrap();
        let out = run_python(
            "import activemap_bridge as b\nprint(*b.decode_action(open('action.bin', 'rb').read()))",
            dir.path(),
        );
        assert_eq!(out.trim(), format!("{step} {name}"));
    }
}

/// The Python client's pure-Python ray caster (the CI scene of the external simulator) sees the
/// same box room as the Rust renderer: same z-depth per pixel, and the same camera pose
/// convention (`camera_pose_from_planar`).
#[test]
fn python_client_ray_caster_matches_the_rust_renderer() {
    use activemap_geometry::{PlanarPose, camera_pose_from_planar};
    let Some(_) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let (x, y, yaw) = (0.3, -0.2, 0.7);
    let scene = super::fixtures::box_room([-2.0, -1.5, 0.0], [2.0, 1.5, 2.5]);
    let mut config = SimConfig::with_resolution(16, 12);
    config.floor_z = Some(0.0);
    config.start = Some(PlanarPose::new(x, y, yaw));
    let mut sim = Simulator::new(scene, config).unwrap();
    let frame = sim.render();
    let code = format!(
        "import activemap_sim_client as c\n\
         scene = c.BoxRoomScene(boxes=[])\n\
         cam = c.RayCastCamera(16, 12, 90.0)\n\
         rgb, depth = cam.render(scene, {x}, {y}, {yaw})\n\
         open('depth.bin', 'wb').write(depth)\n\
         t, q = c.camera_pose({x}, {y}, {yaw})\n\
         print(*t, *q)\n"
    );
    let out = run_python(&code, dir.path());
    let depth: Vec<f32> = std::fs::read(dir.path().join("depth.bin"))
        .unwrap()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect();
    assert_eq!(depth.len(), frame.depth.len());
    for (i, (p, r)) in depth.iter().zip(&frame.depth).enumerate() {
        assert!(*r > 0.0, "pixel {i}: the Rust renderer saw no surface");
        assert!((p - r).abs() <= 1e-4 * r, "pixel {i}: python {p} rust {r}");
    }
    let pose: Vec<f64> = out.split_whitespace().map(|v| v.parse().unwrap()).collect();
    let truth = camera_pose_from_planar(&PlanarPose::new(x, y, yaw), 0.0, 0.88);
    let t = truth.translation.vector;
    let q = truth.rotation.coords; // x, y, z, w
    // A quaternion and its negation are the same rotation.
    let sign = if (q[3] * pose[6]) < 0.0 { -1.0 } else { 1.0 };
    for k in 0..3 {
        assert!(
            (pose[k] - t[k]).abs() < 1e-12,
            "translation {pose:?} vs {t:?}"
        );
    }
    for k in 0..4 {
        assert!(
            (sign * pose[3 + k] - q[k]).abs() < 1e-12,
            "rotation {pose:?} vs {q:?}"
        );
    }
}

/// The Python client's noise (`python/activemap_noise.py`) against the Rust model: the
/// `realistic` preset equals [`crate::NoiseConfig::realistic`] value for value; on flat depth
/// images (seeded) the spread of the readings is σ0 + c2·z² at 1, 2 and 4 m and their mean z,
/// the dropout rate is the configured 1 %, readings beyond the maximum range are 0, about half
/// the pixels beside a depth step are dropped, the colour spread is σ = 2 levels, and the
/// actuation spreads are the configured ones; bad values are refused naming the field.
#[test]
fn python_noise_matches_the_rust_model() {
    let Some(_) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let code = r#"
import array, json, math, activemap_noise as n

def moments(xs):
    m = sum(xs) / len(xs)
    return m, math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1))

cfg = n.parse_noise("realistic")
out = {"preset": cfg, "depth": {}}
w = 100
for z in (1.0, 2.0, 4.0, 12.0):
    flat = array.array("f", [z] * w * w).tobytes()
    rgb, d = n.SensorNoise(cfg, 7).apply(bytes([128]) * 3 * w * w, flat, w)
    v = array.array("f"); v.frombytes(d)
    valid = [x for x in v if x > 0]
    m, s = moments(valid) if len(valid) > 1 else (0.0, 0.0)
    out["depth"][str(z)] = {"valid": len(valid) / len(v), "mean": m, "std": s}
    if z == 1.0:
        out["rgb_std"] = moments(list(rgb))[1]
no_dropout = n.parse_noise({"preset": "realistic", "depth": {"dropout": 0}})
step = array.array("f", [1.0 if x < w // 2 else 2.0 for _ in range(w) for x in range(w)]).tobytes()
_, d = n.SensorNoise(no_dropout, 9).apply(bytes(3 * w * w), step, w)
v = array.array("f"); v.frombytes(d)
beside = [v[y * w + x] for y in range(w) for x in (w // 2 - 1, w // 2)]
inside = [v[y * w + x] for y in range(w) for x in range(w) if x not in (w // 2 - 1, w // 2)]
out["edge_dropped"] = sum(1 for x in beside if x == 0) / len(beside)
out["inside_dropped"] = sum(1 for x in inside if x == 0) / len(inside)
a = n.ActuationNoise(cfg, 5)
fwd = [a.forward(0.05) for _ in range(20000)]
out["forward"] = moments([f[0] for f in fwd])
out["heading_deg"] = moments([math.degrees(f[1]) for f in fwd])
out["turn_deg"] = moments([math.degrees(a.turn(math.radians(5.0))) for _ in range(20000)])
errors = []
for bad in ["loud", {"depth": {"sigma": 1}}, {"depth": {"dropout": 2}}, {"rgb": {"sigma": "x"}},
            {"depth": {"min_range": 3, "max_range": 2}}, {"wind": {}}]:
    try:
        n.parse_noise(bad)
        errors.append("accepted")
    except n.NoiseConfigError as e:
        errors.append(str(e))
out["errors"] = errors
print(json.dumps(out))
"#;
    let out: serde_json::Value = serde_json::from_str(&run_python(code, dir.path())).unwrap();
    let rust = serde_json::to_value(crate::NoiseConfig::realistic()).unwrap();
    assert_eq!(
        out["preset"], rust,
        "the Python preset differs from the Rust one"
    );
    let depth = crate::DepthNoise::REALISTIC;
    let f = |v: &serde_json::Value| v.as_f64().unwrap();
    for z in [1.0, 2.0, 4.0] {
        let s = &out["depth"][format!("{z:?}")];
        let sigma = depth.sigma_at(z);
        // 10⁴ pixels: the spread within 5 %, the mean within 4 standard errors.
        assert!(
            (f(&s["std"]) / sigma - 1.0).abs() < 0.05,
            "z {z}: {s}, σ {sigma}"
        );
        assert!((f(&s["mean"]) - z).abs() < 4.0 * sigma / 99.0, "z {z}: {s}");
        assert!(
            (f(&s["valid"]) - (1.0 - depth.dropout)).abs() < 0.004,
            "z {z}: {s}"
        );
    }
    assert_eq!(f(&out["depth"]["12.0"]["valid"]), 0.0, "beyond max_range");
    assert!(
        (f(&out["edge_dropped"]) - depth.edge_dropout).abs() < 0.12,
        "{out}"
    );
    assert_eq!(f(&out["inside_dropped"]), 0.0, "{out}");
    // round(σ·n) has variance σ² + 1/12.
    let rgb = (crate::ColourNoise::REALISTIC.sigma.powi(2) + 1.0 / 12.0).sqrt();
    assert!((f(&out["rgb_std"]) / rgb - 1.0).abs() < 0.05, "{out}");
    let act = crate::ActuationNoise::REALISTIC;
    let spread = |key: &str, mean: f64, sigma: f64| {
        let (m, s) = (f(&out[key][0]), f(&out[key][1]));
        assert!(
            (s / sigma - 1.0).abs() < 0.03,
            "{key}: σ {s}, expected {sigma}"
        );
        assert!((m - mean).abs() < 4.0 * sigma / 141.0, "{key}: mean {m}");
    };
    spread("forward", 0.05, act.forward_sigma(0.05));
    spread("heading_deg", 0.0, act.heading_sigma_deg);
    spread("turn_deg", 5.0, act.turn_sigma_deg);
    let errors: Vec<&str> = out["errors"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e.as_str().unwrap())
        .collect();
    for (error, names) in errors.iter().zip([
        "unknown preset 'loud'",
        "noise.depth: unknown field `sigma`",
        "noise.depth.dropout",
        "noise.rgb.sigma: expected a number",
        "noise.depth.max_range",
        "noise: unknown key `wind`",
    ]) {
        assert!(error.contains(names), "{error:?} does not name {names:?}");
    }
}
