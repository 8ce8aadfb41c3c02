//! `activemap scene inspect`: a tilted y-down scan of a furnished room placed with
//! `up_axis=auto floor=auto` and nothing else (report, navigable floor, rooms, PNG); a bare
//! closed box refused with its candidates; a procedural house inspected as is.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Duration;

use super::harness::run;

const TIMEOUT: Duration = Duration::from_secs(120);

/// Writes an OBJ of axis-aligned quads (each `[lo, hi]` with one flat coordinate, wound to
/// face `facing`), every point turned by `pitch_deg` about x and then written y-down
/// (`(x, y, z)` world → `(x, −z, y)` file).
fn write_scan(path: &Path, quads: &[([f64; 3], [f64; 3], [f64; 3])], pitch_deg: f64) {
    let (s, c) = pitch_deg.to_radians().sin_cos();
    let mut text = String::new();
    let mut n = 0;
    for (lo, hi, facing) in quads {
        let flat = (0..3).find(|&k| lo[k] == hi[k]).expect("a flat quad");
        let (u, v) = ((flat + 1) % 3, (flat + 2) % 3);
        let mut corners = Vec::new();
        for (a, b) in [
            (lo[u], lo[v]),
            (hi[u], lo[v]),
            (hi[u], hi[v]),
            (lo[u], hi[v]),
        ] {
            let mut p = *lo;
            p[u] = a;
            p[v] = b;
            corners.push(p);
        }
        // (u × v) is +flat; reverse when the quad should face the other way.
        if facing[flat] < 0.0 {
            corners.reverse();
        }
        for [x, y, z] in corners {
            let (y, z) = (c * y - s * z, s * y + c * z);
            writeln!(text, "v {x} {} {y}", -z).unwrap();
        }
        writeln!(text, "f {} {} {}", n + 1, n + 2, n + 3).unwrap();
        writeln!(text, "f {} {} {}", n + 1, n + 3, n + 4).unwrap();
        n += 4;
    }
    std::fs::write(path, text).unwrap();
}

/// A 4 m × 3 m room: floor, four 2.5 m walls, optionally a ceiling, optionally a bed.
fn room(ceiling: bool, bed: bool) -> Vec<([f64; 3], [f64; 3], [f64; 3])> {
    let (x, y, h) = (4.0, 3.0, 2.5);
    let mut q = vec![
        ([0.0, 0.0, 0.0], [x, y, 0.0], [0.0, 0.0, 1.0]),
        ([0.0, 0.0, 0.0], [x, 0.0, h], [0.0, 1.0, 0.0]),
        ([0.0, y, 0.0], [x, y, h], [0.0, -1.0, 0.0]),
        ([0.0, 0.0, 0.0], [0.0, y, h], [1.0, 0.0, 0.0]),
        ([x, 0.0, 0.0], [x, y, h], [-1.0, 0.0, 0.0]),
    ];
    if ceiling {
        q.push(([0.0, 0.0, h], [x, y, h], [0.0, 0.0, -1.0]));
    }
    if bed {
        q.extend([
            ([0.3, 0.3, 0.5], [1.7, 2.3, 0.5], [0.0, 0.0, 1.0]),
            ([1.7, 0.3, 0.0], [1.7, 2.3, 0.5], [1.0, 0.0, 0.0]),
            ([0.3, 2.3, 0.0], [1.7, 2.3, 0.5], [0.0, 1.0, 0.0]),
        ]);
    }
    q
}

#[test]
fn a_pitched_y_down_scan_inspects_with_up_axis_auto_and_nothing_else() {
    let dir = tempfile::tempdir().unwrap();
    let scan = dir.path().join("scan.obj");
    write_scan(&scan, &room(false, true), -34.0);
    let out = run(
        &["scene", "inspect", "scan.obj", "up_axis=auto", "floor=auto"],
        dir.path(),
        TIMEOUT,
    );
    assert!(out.status.success(), "{}\n{}", out.stdout, out.stderr);
    let text = &out.stdout;
    eprintln!("{text}");
    assert!(
        text.contains("up axis auto")
            && text.contains("read as up axis -y and removed a tilt of 34.00°")
            && text.contains("runner-up")
            && text.contains("floor: z = 0.000 m")
            && text.contains("rooms: 1 ")
            && text.contains("top-down view: scan.top.png"),
        "{text}"
    );
    let area: f64 = text
        .lines()
        .find_map(|l| l.strip_prefix("navigable floor: "))
        .and_then(|l| l.split(' ').next())
        .and_then(|v| v.parse().ok())
        .expect("the navigable floor area");
    // 12 m² less the bed (2.8 m²) and a robot radius along the walls.
    assert!((7.0..10.0).contains(&area), "navigable {area} m²");
    let png = std::fs::read(dir.path().join("scan.top.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");
}

#[test]
fn a_bare_closed_box_is_refused_listing_the_keys_that_pick_each_face() {
    let dir = tempfile::tempdir().unwrap();
    write_scan(&dir.path().join("box.obj"), &room(true, false), -20.0);
    let out = run(
        &["scene", "inspect", "box.obj", "up_axis=auto", "floor=auto"],
        dir.path(),
        TIMEOUT,
    );
    assert!(!out.status.success());
    // The six faces, each with its keys; the four the pitch tilted with a rotation.
    let listed: Vec<&str> = out
        .stderr
        .lines()
        .filter(|l| l.contains("[up_axis: "))
        .collect();
    let turned = listed
        .iter()
        .filter(|l| l.contains("transform: {rotate_deg: [20.00, 0.00, 0.00]}"))
        .count();
    assert!(
        out.stderr.contains("cannot tell up") && listed.len() == 6 && turned == 4,
        "{}",
        out.stderr
    );
    assert!(!dir.path().join("box.top.png").exists());
}

#[test]
fn a_procedural_house_inspects_as_is_and_bad_keys_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let out = run(
        &["scene", "inspect", "house:3", "--png", "house.png"],
        dir.path(),
        TIMEOUT,
    );
    assert!(out.status.success(), "{}", out.stderr);
    assert!(
        out.stdout.contains("placement: a procedural house") && out.stdout.contains("rooms: "),
        "{}",
        out.stdout
    );
    assert!(dir.path().join("house.png").is_file());
    let out = run(
        &["scene", "inspect", "house:3", "up_axis=auto"],
        dir.path(),
        TIMEOUT,
    );
    assert!(
        !out.status.success() && out.stderr.contains("procedural houses"),
        "{}",
        out.stderr
    );
    let out = run(
        &["scene", "inspect", "x.obj", "scale=2"],
        dir.path(),
        TIMEOUT,
    );
    assert!(
        !out.status.success() && out.stderr.contains("unknown field `scale`"),
        "{}",
        out.stderr
    );
}
