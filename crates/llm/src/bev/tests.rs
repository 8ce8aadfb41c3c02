//! Tests of the BEV on a synthetic room: 6 m × 4 m, a grey floor, dark walls up to 0.8 m, a
//! magenta ceiling Gaussian above the camera and a cyan one larger than the size limit.

use super::*;

const CAMERA_Z: f64 = 1.0;
const CEILING_AT: [f64; 2] = [1.5, 2.0];
const LARGE_AT: [f64; 2] = [4.5, 0.5];
const IDENTITY: [f64; 4] = [1.0, 0.0, 0.0, 0.0];

fn room() -> Gaussians<f32> {
    let mut g = Gaussians::<f32>::new();
    // Floor: a 0.25 m grid of flat grey discs.
    for i in 0..=24 {
        for j in 0..=16 {
            let p = [i as f64 * 0.25, j as f64 * 0.25, 0.0];
            g.push(p, [0.75; 3], IDENTITY, 0.9, [0.09, 0.09, 0.01]);
        }
    }
    // Walls on the four sides, three layers up to 0.8 m.
    let mut wall = |x: f64, y: f64| {
        for z in [0.1, 0.45, 0.8] {
            g.push([x, y, z], [0.3, 0.3, 0.35], IDENTITY, 0.95, [0.06; 3]);
        }
    };
    for i in 0..=30 {
        let x = i as f64 * 0.2;
        wall(x, 0.0);
        wall(x, 4.0);
    }
    for j in 1..20 {
        let y = j as f64 * 0.2;
        wall(0.0, y);
        wall(6.0, y);
    }
    // Above the camera: the ceiling cut removes it.
    g.push(
        [CEILING_AT[0], CEILING_AT[1], 2.5],
        [1.0, 0.0, 1.0],
        IDENTITY,
        0.99,
        [0.08; 3],
    );
    // Below the camera but larger than 0.1 m: the size limit removes it.
    g.push(
        [LARGE_AT[0], LARGE_AT[1], 0.5],
        [0.0, 1.0, 1.0],
        IDENTITY,
        0.99,
        [0.3, 0.05, 0.05],
    );
    g
}

/// Candidate `i` of `n` on a grid in the right half of the room.
fn candidates(n: usize) -> Vec<[f64; 2]> {
    (0..n)
        .map(|i| [3.3 + 0.7 * (i % 4) as f64, 1.2 + 0.8 * (i / 4) as f64])
        .collect()
}

fn marks() -> Annotations {
    Annotations {
        robot: [1.0, 3.0, 0.3],
        path: vec![[0.5, 0.5], [2.5, 0.5], [2.5, 2.5], [1.0, 3.0]],
        last_frontier: Some([4.6, 3.6]),
        candidates: candidates(12),
    }
}

fn bev() -> Bev {
    render_bev(&room(), CAMERA_Z, &marks(), &BevConfig::default()).unwrap()
}

/// The pixel nearest a world point.
fn pixel_at(bev: &Bev, world: [f64; 2]) -> [u8; 3] {
    let p = bev.pixel_of(world).map(|v| v.round() as usize);
    bev.pixel(p[0], p[1])
}

fn is_red(p: [u8; 3]) -> bool {
    p[0] >= 170 && p[1] <= 80 && p[2] <= 80
}
fn is_green(p: [u8; 3]) -> bool {
    p[1] >= 130 && p[0] <= 80 && p[2] <= 80
}
fn is_blue(p: [u8; 3]) -> bool {
    p[2] >= 200 && p[0] <= 60 && p[1] <= 120
}
fn is_yellow(p: [u8; 3]) -> bool {
    p[0] >= 200 && p[1] >= 170 && p[2] <= 60
}

#[test]
fn bev_star_path_and_diamond_land_on_their_pixels() {
    let bev = bev();
    let a = marks();
    assert_eq!(bev.width.max(bev.height), 800);
    assert_eq!(bev.rgb.len(), bev.width * bev.height * 3);
    assert!(is_blue(pixel_at(&bev, [a.robot[0], a.robot[1]])));
    // Along the heading (yaw 0.3) the star's tip and tick are blue; behind it, between two
    // tips, the floor shows.
    let (c, s) = (0.3f64.cos(), 0.3f64.sin());
    let m = bev.window.metres_per_pixel;
    let ahead = [a.robot[0] + 18.0 * m * c, a.robot[1] + 18.0 * m * s];
    assert!(
        is_blue(pixel_at(&bev, ahead)),
        "{:?}",
        pixel_at(&bev, ahead)
    );
    let behind = [a.robot[0] - 13.0 * m * c, a.robot[1] - 13.0 * m * s];
    assert!(!is_blue(pixel_at(&bev, behind)));
    // Path: points on each segment, away from the star.
    for w in [[1.5, 0.5], [2.0, 0.5], [2.5, 1.0], [2.5, 2.0], [2.0, 2.667]] {
        assert!(
            is_green(pixel_at(&bev, w)),
            "{w:?}: {:?}",
            pixel_at(&bev, w)
        );
    }
    // Off the path: not green.
    for w in [[1.5, 0.7], [2.7, 1.5], [1.5, 1.5]] {
        assert!(!is_green(pixel_at(&bev, w)), "{w:?}");
    }
    let f = a.last_frontier.unwrap();
    assert!(is_yellow(pixel_at(&bev, f)));
    assert!(!is_yellow(pixel_at(&bev, [f[0] + 20.0 * m, f[1]])));
    // Nothing else is that yellow or that blue far from the marks.
    for y in 0..bev.height {
        for x in 0..bev.width {
            let p = bev.pixel(x, y);
            let near = |w: [f64; 2], r: f64| {
                let q = bev.pixel_of(w);
                (q[0] - x as f64).hypot(q[1] - y as f64) <= r
            };
            if is_yellow(p) {
                assert!(near(f, 13.0), "yellow at ({x}, {y})");
            }
            if is_blue(p) {
                assert!(near([a.robot[0], a.robot[1]], 28.0), "blue at ({x}, {y})");
            }
        }
    }
}

#[test]
fn bev_window_holds_the_map_and_every_mark() {
    let g = room();
    let mut a = marks();
    // A candidate outside the mapped room widens the window.
    a.candidates.push([-2.0, 5.0]);
    let bev = render_bev(&g, CAMERA_Z, &a, &BevConfig::default()).unwrap();
    assert_eq!(bev.width.max(bev.height), 800);
    let inside = |w: [f64; 2], room_px: f64| {
        let p = bev.pixel_of(w);
        p[0] >= room_px
            && p[1] >= room_px
            && p[0] <= bev.width as f64 - 1.0 - room_px
            && p[1] <= bev.height as f64 - 1.0 - room_px
    };
    for p in a.points() {
        assert!(inside(p, 25.0), "{p:?} at {:?}", bev.pixel_of(p));
    }
    for corner in [[0.0, 0.0], [6.0, 4.0]] {
        assert!(inside(corner, 25.0));
    }
    // The stages run one by one give the same image.
    let config = BevConfig::default();
    let window = bev_window(&g, CAMERA_Z, &a, &config).unwrap();
    assert_eq!(window, bev.window);
    let map = render_map(&g, CAMERA_Z, &window, &config).unwrap();
    assert_eq!(annotate(map, &a, &config).unwrap(), bev);
}

#[test]
fn bev_numbers_sit_at_their_candidates_and_nowhere_else() {
    let bev = bev();
    let a = marks();
    let n = a.candidates.len();
    assert!(n >= 10);
    assert_eq!(bev.labels.len(), n);
    let label_px = BevConfig::default().label_px as f64;
    // Per candidate: the red pixels found within a box around its pixel.
    let (half_w, half_h) = (0.9 * label_px, 0.6 * label_px);
    let mut extent = vec![[f64::INFINITY, f64::NEG_INFINITY]; n];
    let mut count = vec![0usize; n];
    for y in 0..bev.height {
        for x in 0..bev.width {
            if !is_red(bev.pixel(x, y)) {
                continue;
            }
            let owner = a.candidates.iter().position(|&c| {
                let q = bev.pixel_of(c);
                (x as f64 - q[0]).abs() <= half_w && (y as f64 - q[1]).abs() <= half_h
            });
            let Some(i) = owner else {
                panic!("red pixel ({x}, {y}) far from every candidate");
            };
            count[i] += 1;
            extent[i][0] = extent[i][0].min(x as f64);
            extent[i][1] = extent[i][1].max(x as f64);
            // Inside the reported ink box too.
            let ink = bev.labels[i].ink;
            assert!(
                x as f64 >= ink[0] - 1.0
                    && x as f64 <= ink[2] + 1.0
                    && y as f64 >= ink[1] - 1.0
                    && y as f64 <= ink[3] + 1.0
            );
        }
    }
    for (i, label) in bev.labels.iter().enumerate() {
        assert_eq!(
            (label.index, label.text.as_str()),
            (i, i.to_string().as_str())
        );
        let q = bev.pixel_of(a.candidates[i]);
        assert_eq!(label.centre, q);
        let ink = label.ink;
        let centre = [0.5 * (ink[0] + ink[2]), 0.5 * (ink[1] + ink[3])];
        assert!((centre[0] - q[0]).abs() < 0.5 && (centre[1] - q[1]).abs() < 0.5);
        // Digits are ~0.73 em tall in DejaVu Sans Bold.
        let tall = ink[3] - ink[1];
        assert!(tall > 0.6 * label_px && tall < 0.85 * label_px, "{tall}");
        assert!(count[i] >= 40, "label {i}: {} red pixels", count[i]);
    }
    // Two-digit labels are about twice as wide as one-digit ones.
    let width = |i: usize| extent[i][1] - extent[i][0];
    for i in 10..n {
        assert!(width(i) > 1.5 * width(0), "{} vs {}", width(i), width(0));
    }
}

#[test]
fn bev_png_decodes_to_the_same_pixels() {
    let bev = bev();
    let png = bev.png();
    assert!(png.starts_with(b"\x89PNG\r\n\x1a\n"));
    let decoded = image::load_from_memory(&png).unwrap().to_rgb8();
    assert_eq!(
        (decoded.width() as usize, decoded.height() as usize),
        (bev.width, bev.height)
    );
    assert_eq!(decoded.into_raw(), bev.rgb);
    // Deterministic: the same inputs give the same bytes.
    assert_eq!(self::bev().png(), png);
}

#[test]
fn bev_drops_the_ceiling_and_large_gaussians() {
    let g = room();
    let magenta = |p: [u8; 3]| p[0] > 200 && p[2] > 200 && p[1] < 120;
    let cyan = |p: [u8; 3]| p[1] > 200 && p[2] > 200 && p[0] < 120;
    let bev = bev();
    assert!(bev.rgb.chunks_exact(3).all(|p| {
        let p = [p[0], p[1], p[2]];
        !magenta(p) && !cyan(p)
    }));
    // Where they would be, the floor shows.
    for w in [CEILING_AT, LARGE_AT] {
        let p = pixel_at(&bev, w);
        assert!(p.iter().all(|&v| (170..=215).contains(&v)), "{w:?}: {p:?}");
    }
    // Control: with the camera above the ceiling and no size limit both appear.
    let config = BevConfig {
        max_gaussian_size_m: 1.0,
        ..BevConfig::default()
    };
    let all = render_bev(&g, 3.0, &marks(), &config).unwrap();
    assert!(magenta(pixel_at(&all, CEILING_AT)));
    assert!(cyan(pixel_at(&all, LARGE_AT)));
}

#[test]
fn bev_of_an_empty_map_is_cropped_to_the_marks() {
    let empty = Gaussians::<f32>::new();
    let lone = Annotations {
        robot: [2.0, -1.0, 0.0],
        ..Annotations::default()
    };
    let bev = render_bev(&empty, CAMERA_Z, &lone, &BevConfig::default()).unwrap();
    assert_eq!((bev.width, bev.height), (800, 800));
    assert!(is_blue(pixel_at(&bev, [2.0, -1.0])));
    assert_eq!(bev.pixel(0, 0), [255; 3]);
    assert!(bev.labels.is_empty());
    // Everything cut away by the ceiling: the same as empty, cropped to the marks.
    let below = render_bev(&room(), -1.0, &marks(), &BevConfig::default()).unwrap();
    let m = marks();
    let window = bev_window(&empty, CAMERA_Z, &m, &BevConfig::default()).unwrap();
    assert_eq!(below.window, window);
    assert!(is_blue(pixel_at(&below, [m.robot[0], m.robot[1]])));
}

#[test]
fn bev_rejects_non_finite_inputs_naming_them() {
    let g = room();
    let config = BevConfig::default();
    let err = |a: &Annotations, h: f64| render_bev(&g, h, a, &config).unwrap_err().to_string();
    let mut a = marks();
    a.candidates[2][1] = f64::NAN;
    assert!(
        err(&a, CAMERA_Z).contains("candidate 2"),
        "{}",
        err(&a, CAMERA_Z)
    );
    let mut a = marks();
    a.path[1][0] = f64::INFINITY;
    assert!(err(&a, CAMERA_Z).contains("path point 1"));
    let mut a = marks();
    a.robot[2] = f64::NAN;
    assert!(err(&a, CAMERA_Z).contains("robot pose"));
    let mut a = marks();
    a.last_frontier = Some([0.0, f64::NAN]);
    assert!(err(&a, CAMERA_Z).contains("last frontier"));
    assert!(err(&marks(), f64::NAN).contains("camera height"));
    let mut broken = room();
    broken.flags.pop();
    let e = render_bev(&broken, CAMERA_Z, &marks(), &config).unwrap_err();
    assert!(e.to_string().contains("flags"), "{e}");
}

#[test]
fn bev_config_defaults_validation_and_unknown_fields() {
    let c: BevConfig = serde_json::from_str("{}").unwrap();
    assert_eq!(c, BevConfig::default());
    assert_eq!((c.long_side_px, c.max_gaussian_size_m), (800, 0.1));
    c.validate().unwrap();
    let c: BevConfig = serde_json::from_str(r#"{"long_side_px": 512, "margin_m": 0.2}"#).unwrap();
    assert_eq!((c.long_side_px, c.margin_m, c.label_px), (512, 0.2, 28.0));
    let e = serde_json::from_str::<BevConfig>(r#"{"long_side": 512}"#).unwrap_err();
    assert!(e.to_string().contains("long_side"), "{e}");
    let bad = [
        BevConfig {
            long_side_px: 10,
            ..BevConfig::default()
        },
        BevConfig {
            long_side_px: 128,
            ..BevConfig::default()
        },
        BevConfig {
            label_px: 0.0,
            ..BevConfig::default()
        },
        BevConfig {
            margin_m: f64::NAN,
            ..BevConfig::default()
        },
        BevConfig {
            max_gaussian_size_m: -1.0,
            ..BevConfig::default()
        },
    ];
    let fields = [
        "long_side_px",
        "long_side_px",
        "label_px",
        "margin_m",
        "max_gaussian_size_m",
    ];
    for (c, field) in bad.iter().zip(fields) {
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains(&format!("bev.{field}")), "{e}");
        assert!(render_bev(&room(), CAMERA_Z, &marks(), c).is_err());
    }
    // A smaller image at a valid size.
    let small = BevConfig {
        long_side_px: 400,
        label_px: 20.0,
        ..BevConfig::default()
    };
    let bev = render_bev(&room(), CAMERA_Z, &marks(), &small).unwrap();
    assert_eq!(bev.width.max(bev.height), 400);
}

/// A house-like map of about 150k Gaussians: 12 m × 9 m, floor, walls with rooms, furniture,
/// a ceiling; scales log-uniform from 1 to 8 cm (a few larger).
fn house(n: usize) -> Gaussians<f32> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let mut g = Gaussians::<f32>::new();
    let walls_x = [0.0, 4.0, 8.0, 12.0];
    let walls_y = [0.0, 4.5, 9.0];
    for k in 0..n {
        let kind = k % 20;
        let mean = match kind {
            // Floor (45 %).
            0..=8 => [
                rng.random_range(0.0..12.0),
                rng.random_range(0.0..9.0),
                rng.random_range(-0.02..0.02),
            ],
            // Walls (35 %).
            9..=15 => {
                let z = rng.random_range(0.0..2.6);
                if rng.random_bool(0.5) {
                    let x = walls_x[rng.random_range(0..walls_x.len())];
                    [
                        x + rng.random_range(-0.03..0.03),
                        rng.random_range(0.0..9.0),
                        z,
                    ]
                } else {
                    let y = walls_y[rng.random_range(0..walls_y.len())];
                    [
                        rng.random_range(0.0..12.0),
                        y + rng.random_range(-0.03..0.03),
                        z,
                    ]
                }
            }
            // Furniture (10 %).
            16 | 17 => [
                rng.random_range(0.5..11.5),
                rng.random_range(0.5..8.5),
                rng.random_range(0.0..1.2),
            ],
            // Ceiling (10 %).
            _ => [
                rng.random_range(0.0..12.0),
                rng.random_range(0.0..9.0),
                rng.random_range(2.55..2.65),
            ],
        };
        let scale = [0; 3].map(|_| 10f64.powf(rng.random_range(-2.0..-1.1)));
        let q = [0; 4].map(|_| rng.random_range(-1.0..1.0));
        let rgb = [0; 3].map(|_| rng.random_range(0.1..0.9));
        g.push(mean, rgb, q, rng.random_range(0.3..1.0), scale);
    }
    g
}

/// The planner's BEV overhead at 800 px on ~150k Gaussians: window, render, annotate, PNG.
/// `cargo test -p activemap-llm --release --lib bev -- --ignored --nocapture`; with
/// `BEV_WRITE_DIR` set it also writes `bev-room.png` and `bev-house.png` there to look at.
#[test]
#[ignore = "timing; run in release with --nocapture"]
fn bev_timing_150k_gaussians() {
    use std::time::Instant;
    let g = house(150_000);
    let a = Annotations {
        robot: [2.0, 2.0, 0.5],
        path: (0..200)
            .map(|i| [1.0 + 0.05 * i as f64, 2.0 + 0.02 * i as f64])
            .collect(),
        last_frontier: Some([9.0, 7.0]),
        candidates: (0..15).map(|i| [0.7 * i as f64 + 1.0, 6.5]).collect(),
    };
    let config = BevConfig::default();
    let camera_z = 0.88;
    let mut rows = Vec::new();
    for _ in 0..9 {
        let t0 = Instant::now();
        let window = bev_window(&g, camera_z, &a, &config).unwrap();
        let t1 = Instant::now();
        let map = render_map(&g, camera_z, &window, &config).unwrap();
        let t2 = Instant::now();
        let bev = annotate(map, &a, &config).unwrap();
        let t3 = Instant::now();
        let png = bev.png();
        let t4 = Instant::now();
        assert!(png.len() > 1000);
        let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
        rows.push([ms(t0, t1), ms(t1, t2), ms(t2, t3), ms(t3, t4), ms(t0, t4)]);
    }
    if let Some(dir) = std::env::var_os("BEV_WRITE_DIR") {
        let dir = std::path::PathBuf::from(dir);
        let house = render_bev(&g, camera_z, &a, &config).unwrap();
        std::fs::write(dir.join("bev-house.png"), house.png()).unwrap();
        std::fs::write(dir.join("bev-room.png"), bev().png()).unwrap();
    }
    let median = |k: usize| {
        let mut v: Vec<f64> = rows.iter().map(|r| r[k]).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    println!(
        "BEV 800 px, {} Gaussians, {} threads: window {:.1} ms, render {:.1} ms, annotate \
         {:.1} ms, png {:.1} ms, total {:.1} ms (median of {})",
        g.len(),
        rayon::current_num_threads(),
        median(0),
        median(1),
        median(2),
        median(3),
        median(4),
        rows.len()
    );
}
