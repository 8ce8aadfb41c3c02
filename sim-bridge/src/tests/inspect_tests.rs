//! `inspect`: a tilted y-down scan of two rooms joined by a door, placed with `up_axis: auto`,
//! split into its two rooms, with a top-down view that shows both.

use super::fixtures::{facing_quad as quad, flat, write_obj};
use crate::inspect::{inspect, room_colour};
use crate::scene::Scene;
use crate::{Floor, Placement, SceneSpec, SimConfig, UpAxis};
use nalgebra::{Rotation3, Unit, Vector3};

/// Two 4 m × 4 m rooms side by side (x 0–4 and 4–8), 2.5 m walls, no ceiling, joined by a
/// 0.9 m door at y 1.5–2.4 in the wall x = 4; a bed (top 0.5 m) in the first room.
fn two_rooms() -> Scene {
    let mut s = Scene {
        name: "two rooms".into(),
        ..Scene::default()
    };
    let m = flat(&mut s, [0.7; 3]);
    let h = 2.5;
    quad(
        &mut s,
        [
            [0.0, 0.0, 0.0],
            [8.0, 0.0, 0.0],
            [8.0, 4.0, 0.0],
            [0.0, 4.0, 0.0],
        ],
        [0.0, 0.0, 1.0],
        m,
    );
    quad(
        &mut s,
        [
            [0.0, 0.0, 0.0],
            [8.0, 0.0, 0.0],
            [8.0, 0.0, h],
            [0.0, 0.0, h],
        ],
        [0.0, 1.0, 0.0],
        m,
    );
    quad(
        &mut s,
        [
            [0.0, 4.0, 0.0],
            [8.0, 4.0, 0.0],
            [8.0, 4.0, h],
            [0.0, 4.0, h],
        ],
        [0.0, -1.0, 0.0],
        m,
    );
    quad(
        &mut s,
        [
            [0.0, 0.0, 0.0],
            [0.0, 4.0, 0.0],
            [0.0, 4.0, h],
            [0.0, 0.0, h],
        ],
        [1.0, 0.0, 0.0],
        m,
    );
    quad(
        &mut s,
        [
            [8.0, 0.0, 0.0],
            [8.0, 4.0, 0.0],
            [8.0, 4.0, h],
            [8.0, 0.0, h],
        ],
        [-1.0, 0.0, 0.0],
        m,
    );
    // The dividing wall, both faces, with its door.
    for (y0, y1) in [(0.0, 1.5), (2.4, 4.0)] {
        for facing in [[-1.0f64, 0.0, 0.0], [1.0, 0.0, 0.0]] {
            let x = 4.0 + 0.05 * facing[0] as f32;
            quad(
                &mut s,
                [[x, y0, 0.0], [x, y1, 0.0], [x, y1, h], [x, y0, h]],
                facing,
                m,
            );
        }
    }
    // A bed: top and sides.
    let (a, b) = ([0.3f32, 0.3, 0.0], [1.7f32, 2.3, 0.5]);
    quad(
        &mut s,
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
        &mut s,
        [
            [b[0], a[1], 0.0],
            [b[0], b[1], 0.0],
            [b[0], b[1], b[2]],
            [b[0], a[1], b[2]],
        ],
        [1.0, 0.0, 0.0],
        m,
    );
    quad(
        &mut s,
        [
            [a[0], b[1], 0.0],
            [b[0], b[1], 0.0],
            [b[0], b[1], b[2]],
            [a[0], b[1], b[2]],
        ],
        [0.0, 1.0, 0.0],
        m,
    );
    s.subdivided(2)
}

#[test]
fn a_tilted_scan_of_two_rooms_inspects_as_two_rooms_with_a_top_down_view() {
    let tilt = Rotation3::from_axis_angle(
        &Unit::new_normalize(Vector3::new(0.3, 1.0, 0.2)),
        40f64.to_radians(),
    );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("two_rooms.obj");
    let mut file = two_rooms();
    for v in &mut file.vertices {
        let p = tilt * Vector3::new(v.position[0], v.position[1], v.position[2]).cast::<f64>();
        v.position = UpAxis::NegY.from_world([p.x as f32, p.y as f32, p.z as f32]);
    }
    write_obj(&path, &file);
    let spec = SceneSpec {
        placement: Placement {
            up_axis: Some(UpAxis::Auto),
            floor: Floor::Auto,
            ..Placement::default()
        },
        ..SceneSpec::new(path.to_str().unwrap())
    };
    let found = inspect(&spec, &SimConfig::default()).unwrap();
    let report = found.loaded.placement.as_ref().unwrap();
    eprintln!("{report}");
    assert!(report.auto_up.is_some());
    assert_eq!(found.floor_z, 0.0);
    let area = found.navigation.map().area();
    let rooms = &found.rooms.rooms;
    eprintln!("navigable {area:.2} m², rooms {rooms:?}");
    // 2 × 16 m² less a 0.1 m robot radius along the walls and the bed.
    assert!((22.0..30.0).contains(&area), "navigable {area} m²");
    assert_eq!(rooms.len(), 2, "{rooms:?}");
    for r in rooms {
        assert!((9.0..16.0).contains(&r.area), "{rooms:?}");
    }
    let (a, b) = (rooms[0].centre, rooms[1].centre);
    let apart = ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt();
    assert!((apart - 4.0).abs() < 0.5, "room centres {apart} m apart");
    // The view: the 8 m × 4 m house at 2 cm, turned about z by the levelling (its bounding
    // box at most √(8² + 4²) = 8.95 m long), both room colours present.
    let image = found.top_down(0.02).unwrap();
    let (w, h) = image.dimensions();
    let (long, short) = (w.max(h), w.min(h));
    assert!(
        (400..=450).contains(&long) && (200..=450).contains(&short),
        "{w} × {h}"
    );
    for k in 0..2 {
        let c = room_colour(k);
        let tinted = image.pixels().any(|p| {
            p.0.iter()
                .zip(c)
                .all(|(v, t)| (*v as i32 - t as i32 / 2).abs() <= 128)
                && p.0 != [255; 3]
        });
        assert!(tinted, "room {k} is in the view");
    }
    let png = dir.path().join("top.png");
    assert_eq!(found.write_top_down(&png, 0.02).unwrap(), (w, h));
    assert_eq!(&std::fs::read(&png).unwrap()[1..4], b"PNG");
}
