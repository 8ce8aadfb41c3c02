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
